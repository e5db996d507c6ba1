"""Variable kinds, nominal values and their FMI causality and variability."""

import math

import pytest

from sarcomere.dynamics.components.mechanical import Damper, Fixed, Mass, Spring
from sarcomere.dynamics.errors import ModelError, ParameterError
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.modeling.ports import FLANGE
from sarcomere.dynamics.modeling.variables import Kind, Var


class Drive(Component):
    """An input force on a flange, with a declared output and an explicit nominal."""

    def build(self, b):
        gain = b.parameter("gain", 0.0, "1", "force gain")
        f = b.input("f", "N", "applied force", start=2.0, nominal=5.0)
        fl = b.port("flange", FLANGE)
        b.equation(fl.f, -(1 + gain) * f)
        b.output("f_out", f, "N", "applied force (output)", nominal=3.0)


def damped_mass():
    sys = System("dm")
    fix = sys.add(Fixed("fix"))
    spring = sys.add(Spring("spring", c=250.0))
    damper = sys.add(Damper("damper", d=2.0))
    mass = sys.add(Mass("mass", m=0.5, g=0.0, s_start=-0.04))
    drive = sys.add(Drive("drive"))
    for a, b in ((fix.flange, spring.flange_a), (fix.flange, damper.flange_a)):
        sys.connect(a, b)
    sys.connect(spring.flange_b, mass.flange_a)
    sys.connect(damper.flange_b, mass.flange_a)
    sys.connect(mass.flange_b, drive.flange)
    return sys.flatten()


def test_a_flattened_model_holds_every_kind_as_a_kind():
    model = damped_mass()
    seen = set()
    for var in model.variables.values():
        assert isinstance(var.kind, Kind)
        seen.add(var.kind)
    assert seen == set(Kind)


def test_an_unknown_kind_is_refused_naming_the_variable():
    with pytest.raises(ModelError, match=r"variable 'a\.b' has kind 'stat'; one of \["):
        Var("a.b", "stat", unit="m")


def test_nominal_defaults_to_the_magnitude_of_start_or_value():
    model = damped_mass()
    v = model.variables
    assert v["mass.s"].nominal == 0.04  # |start|
    assert v["mass.v"].nominal == 1.0  # start 0
    assert v["spring.c"].nominal == 250.0  # |value|
    assert v["drive.gain"].nominal == 1.0  # value 0
    assert v["drive.f"].nominal == 5.0  # given
    assert v["drive.f_out"].nominal == 3.0
    assert list(model.nominal("x")) == [0.04, 1.0]
    assert list(model.nominal("u")) == [5.0]
    assert model.nominal("p").shape == (len(model.param_names),)
    assert all(n > 0 and math.isfinite(n) for n in model.nominal("p"))


def test_a_parameter_expression_start_gives_its_default_magnitude_as_nominal():
    class Vessel(Component):
        def build(self, b):
            V0 = b.parameter("V0", 2e-6, "m^3", "volume", low=0.0)
            p_amb = b.parameter("p_amb", 1e5, "Pa", "ambient pressure", low=0.0)
            m = b.state("m_air", V0 * p_amb / 287.0 / 293.0, "kg", "air mass")
            b.der(m, -m)

    sys = System("v")
    sys.add(Vessel("vessel"))
    model = sys.flatten()
    assert model.variables["vessel.m_air"].nominal == pytest.approx(0.2 / 287.0 / 293.0, 1e-15)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_a_nonpositive_or_nonfinite_nominal_is_a_parameter_error(bad):
    with pytest.raises(ParameterError, match=r"parameter 'x\.nominal' = .* allowed: \(0, inf\) m"):
        Var("x", Kind.STATE, unit="m", nominal=bad)


def test_nominal_of_an_unknown_vector_is_refused():
    with pytest.raises(ParameterError, match="parameter 'which' = 'q'"):
        damped_mass().nominal("q")
