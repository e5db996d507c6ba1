"""Instant pneumatics: every chamber at the regulator's outlet pressure, validated against full.

Levels ``instant_pneumatics`` (full mechanics) and ``instant_quasi_static`` (massless SPA
expansion) have no air-mass states and no tubes; measured against ``full`` on the
50 g step of ``step-50g`` (docs/model.md, "Fidelity levels").
"""

from fnmatch import fnmatch

import numpy as np
import pytest

from sarcomere.dynamics import SolverSettings, hanging_load, isometric, simulate
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.components.chains import Myofibril
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.signals import Step

P = "regulator.p_cmd"
INSTANT = ("instant_pneumatics", "instant_quasi_static")


def _stiffest_mode(model, p_cmd):
    """(eigenvalue of largest modulus [1/s], its dominant state by participation) at the
    equilibrium for ``p_cmd``."""
    eq = solve_equilibrium(model, {P: p_cmd})
    A = np.array(model.function("jac")(x=eq.x, z=[], u=eq.u, p=eq.p)["A"])
    vals, right = np.linalg.eig(A)
    k = int(np.argmax(np.abs(vals)))
    share = np.abs(right[:, k] * np.linalg.inv(right)[k, :])
    return vals[k], model.state_names[int(np.argmax(share))]


@pytest.mark.parametrize("level", INSTANT)
def test_equilibria_equal_full_and_chambers_sit_at_the_supply_pressure(level):
    """Same statics: at rest every chamber is at the regulator's pressure in full too."""
    full, inst = hanging_load(3, load_kg=0.05), hanging_load(3, load_kg=0.05, fidelity=level)
    assert not [s for s in inst.state_names if "chamber" in s]
    for p_cmd in (0.0, 0.05e6, 0.1e6):
        ref, eq = solve_equilibrium(full, {P: p_cmd}), solve_equilibrium(inst, {P: p_cmd})
        assert eq["myofibril.length"] == pytest.approx(ref["myofibril.length"], rel=1e-10)
        assert eq["myofibril.actin0.T"] == pytest.approx(ref["myofibril.actin0.T"], rel=1e-9)
        for k in (1, 2, 3):
            assert eq[f"myofibril.aps{k}.chamber.p_gauge"] == pytest.approx(p_cmd, abs=1e-6)
    force = {
        lv: solve_equilibrium(isometric(3, fidelity=lv), {P: 0.1e6})["sensor.f"]
        for lv in ("full", level)
    }
    assert force[level] == pytest.approx(force["full"], rel=1e-8)  # solver tolerance


def test_the_stiffest_mode_is_gone_and_the_next_is_named():
    """full: -2674 1/s, the top chamber's filling (0.37 ms); instant_pneumatics: -2022 1/s,
    the expansion's damping on its 1 g mass (c_e/m_e = 2000 1/s); instant_quasi_static:
    |-118 + 560j| = 573 1/s, the SPA bodies ringing on the I-bands (89 Hz)."""
    for p_cmd in (0.0, 0.1e6):
        lam, state = _stiffest_mode(hanging_load(3, load_kg=0.05), p_cmd)
        assert 2600 < abs(lam) < 2750 and fnmatch(state, "*.aps1.chamber.m_air")
        lam, state = _stiffest_mode(hanging_load(3, load_kg=0.05, fidelity=INSTANT[0]), p_cmd)
        assert 1900 < abs(lam) < 2100 and fnmatch(state, "*.aps?.expansion.v")
        lam, state = _stiffest_mode(hanging_load(3, load_kg=0.05, fidelity=INSTANT[1]), p_cmd)
        assert 560 < abs(lam) < 580 and fnmatch(state, "*.aps?.body.[sv]")


def _step_50g(fidelity):
    """step-50g's scene: 3 APS, 50 g, 0 -> 0.1 MPa at 0.1 s, 2 s, 2 ms output."""
    m = hanging_load(3, load_kg=0.05, fidelity=fidelity)
    return simulate(
        m,
        2.0,
        {P: Step(final=0.1e6, time=0.1, unit="Pa")},
        x0=solve_equilibrium(m, {P: 0.0}).x,
        settings=SolverSettings(rtol=1e-9, atol=1e-12),
        output_interval=2e-3,
        signals=["myofibril.length", "myofibril.aps1.chamber.p_gauge", "regulator.p_out"],
    )


def test_step_response_within_the_measured_error_of_full():
    """Measured: length 1.82 % (instant_pneumatics) and 1.97 % (instant_quasi_static) of
    full's stroke, the top chamber's pressure 3.58 % of its span (the tube's lag in full:
    its square-root flow law lags more than the 0.37 ms of the linearisation)."""
    ref = _step_50g("full")
    bounds = {"instant_pneumatics": 0.019, "instant_quasi_static": 0.021}
    for level, bound in bounds.items():
        res = _step_50g(level)
        for name, limit in (("myofibril.length", bound), ("myofibril.aps1.chamber.p_gauge", 0.037)):
            err = np.max(np.abs(res[name] - ref[name])) / np.ptp(ref[name])
            assert 0.5 * limit < err < limit, (level, name, err)
        np.testing.assert_array_equal(res["myofibril.aps1.chamber.p_gauge"], res["regulator.p_out"])


def test_bad_instant_option_is_refused():
    with pytest.raises(ParameterError, match=r"instant.*'yes'.*True or False"):
        Myofibril("m", 3, APSParams.from_paper(), instant="yes")


def test_rk4_runs_at_a_step_full_refuses():
    """Where the removed modes cost: RK4 at 3.33 ms (3.7x full's 0.909 ms) is stable at
    instant_quasi_static (limit 5.13 ms) and matches its CVODES run; full refuses it."""
    rk4 = SolverSettings(method="rk4", step=0.01 / 3, options=(("on_unstable", "raise"),))
    runs = {}
    for level in ("full", "instant_quasi_static"):
        m = hanging_load(3, load_kg=0.05, fidelity=level)
        x0 = solve_equilibrium(m, {P: 0.0}).x
        step = {P: Step(final=0.1e6, time=0.1, unit="Pa")}
        if level == "full":
            with pytest.raises(ParameterError, match=r"stability limit 0.00104"):
                simulate(m, 0.5, step, x0=x0, settings=rk4, output_interval=0.01)
            continue
        for name, settings in (("rk4", rk4), ("cvodes", SolverSettings(rtol=1e-9, atol=1e-12))):
            runs[name] = simulate(m, 2.0, step, x0=x0, settings=settings, output_interval=0.01)[
                "myofibril.length"
            ]
    err = np.max(np.abs(runs["rk4"] - runs["cvodes"])) / np.ptp(runs["cvodes"])
    assert err < 1e-5  # measured 1.9e-6
