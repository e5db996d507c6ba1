"""Components, connections and flattening, checked on textbook systems with closed forms."""

import math

import numpy as np
import pytest

from sarcomere.dynamics.components.mechanical import (
    Damper,
    Fixed,
    ForceSensor,
    Mass,
    PositionSensor,
    Spring,
)
from sarcomere.dynamics.errors import ModelError, ParameterError
from sarcomere.dynamics.modeling.component import System
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate


def oscillator(m=2.0, c=50.0, d=1.5, s0=0.1, g=0.0):
    sys = System("msd")
    fix = sys.add(Fixed("fix"))
    sensor = sys.add(ForceSensor("sensor"))
    spring = sys.add(Spring("spring", c=c))
    damper = sys.add(Damper("damper", d=d))
    mass = sys.add(Mass("mass", m=m, g=g, s_start=s0))
    pos = sys.add(PositionSensor("pos"))
    sys.connect(fix.flange, sensor.flange_a)
    for a, b in ((sensor.flange_b, spring.flange_a), (sensor.flange_b, damper.flange_a)):
        sys.connect(a, b)
    sys.connect(spring.flange_b, mass.flange_a)
    sys.connect(damper.flange_b, mass.flange_a)
    sys.connect(mass.flange_b, pos.flange)
    return sys.flatten()


def test_msd_is_an_explicit_ode_with_named_states():
    model = oscillator()
    assert model.nz == 0
    assert model.state_names == ["mass.s", "mass.v"]
    assert set(model.output_names) == {"sensor.f", "spring.f", "pos.s"}
    assert model.unit("mass.s") == "m"


def test_msd_natural_frequency_and_damping_ratio():
    m, c, d = 2.0, 50.0, 1.5
    model = oscillator(m, c, d)
    A = np.array(model.function("jac")(x=model.x0(), z=[], u=[], p=model.parameters())["A"])
    lam = np.linalg.eigvals(A)
    wn = math.sqrt(c / m)
    zeta = d / (2 * math.sqrt(c * m))
    assert np.allclose(np.abs(lam), wn, rtol=1e-12)
    assert np.allclose(-lam.real / np.abs(lam), zeta, rtol=1e-12)


def test_msd_free_response_matches_closed_form():
    m, c, d, s0 = 2.0, 50.0, 1.5, 0.1
    model = oscillator(m, c, d, s0)
    res = simulate(model, 3.0, settings=SolverSettings(rtol=1e-10, atol=1e-13))
    wn, zeta = math.sqrt(c / m), d / (2 * math.sqrt(c * m))
    wd = wn * math.sqrt(1 - zeta**2)
    t = res.index
    exact = s0 * np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))
    assert np.max(np.abs(res["mass.s"] - exact)) < 1e-8
    # the sensor reads the spring and damper force on the frame
    assert np.allclose(res["sensor.f"], c * res["mass.s"] + d * res["mass.v"], atol=1e-9)
    assert np.allclose(res["pos.s"], res["mass.s"])


def test_hanging_mass_static_deflection():
    m, c, g = 0.5, 200.0, 9.80665
    model = oscillator(m=m, c=c, d=5.0, s0=0.0, g=g)
    res = simulate(model, 5.0, settings=SolverSettings(rtol=1e-10, atol=1e-13))
    assert res.final("mass.s") == pytest.approx(m * g / c, rel=1e-6)


def test_energy_is_conserved_without_damping():
    model = oscillator(d=0.0)
    res = simulate(model, 2.0, settings=SolverSettings(rtol=1e-11, atol=1e-14))
    E = model.function("energy")
    p = model.parameters()
    energies = [
        float(E(x=[s, v], z=[], u=[], p=p)["E"])
        for s, v in zip(res["mass.s"], res["mass.v"], strict=True)
    ]
    assert np.ptp(energies) < 1e-9 * energies[0]
    assert energies[0] == pytest.approx(0.5 * 50.0 * 0.1**2)


def test_unconnected_spring_is_structurally_singular():
    sys = System("bad")
    sys.add(Spring("spring", c=1.0))
    with pytest.raises(ModelError, match="singular"):
        sys.flatten()


def test_connecting_different_port_kinds_is_refused():
    from sarcomere.dynamics.components.environment import Environment
    from sarcomere.dynamics.components.pneumatic import Regulator

    sys = System("bad")
    sys.add(Environment("ambient"))
    src = sys.add(Regulator("src"))
    fix = sys.add(Fixed("fix"))
    with pytest.raises(ModelError, match="cannot connect"):
        sys.connect(src.port, fix.flange)


def test_bad_parameter_names_value_and_range():
    with pytest.raises(ParameterError, match=r"'mass.m' = -1.0.*\[1e-12, inf\) kg"):
        sys = System("bad")
        sys.add(Mass("mass", m=-1.0))


def test_parameter_override_with_units_and_unknown_name():
    model = oscillator()
    p = model.parameters({"mass.m": "500 g"})
    assert p[model.param_names.index("mass.m")] == pytest.approx(0.5)
    with pytest.raises(ParameterError, match="did you mean"):
        model.parameters({"mass.mm": 1.0})
    with pytest.raises(ParameterError, match="wrong dimension"):
        model.parameters({"mass.m": "3 m"})


def test_duplicate_component_names_are_refused():
    sys = System("bad")
    sys.add(Fixed("a"))
    with pytest.raises(ModelError, match="two components named 'a'"):
        sys.add(Fixed("a"))


def test_component_name_must_be_identifier():
    for bad in ("not a name", "1st", "a.b", "", "a__b"):
        with pytest.raises(
            ModelError, match="must be letters, digits and single inner underscores"
        ):
            Fixed(bad)
    with pytest.raises(ModelError, match="must be letters, digits and single inner underscores"):
        System("my system")
