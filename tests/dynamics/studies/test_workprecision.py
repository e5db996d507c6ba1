"""Tests of sarcomere.dynamics.studies.workprecision: metric, records, interpolation, scenarios."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from sarcomere.dynamics.results import Result
from sarcomere.dynamics.signals import Step
from sarcomere.dynamics.simulation.simulate import SolverSettings
from sarcomere.dynamics.studies import workprecision as wp

TINY = wp.Plan(
    tolerances=(1e-3, 1e-5, 1e-7),
    steps={"rk4": (1e-3, 2.5e-4)},
    repeats=1,
    budget_s=0.05,
    check_rtol=1e-7,
)


@pytest.fixture(scope="module")
def small():
    """The step scenario for one APS, 0.4 s, with its reference."""
    sc = dataclasses.replace(wp.scenarios(1)["step"], t_final=0.4, n_out=41)
    return sc, wp.reference(sc, TINY.check_rtol)


def test_error_metric_scales_each_state_by_its_magnitude():
    X = np.array([[1.0, 100.0], [2.0, 200.0]])
    res = Result("time", "s", np.array([0.0, 1.0]), {}, {})
    ref = wp.Reference(res, X, np.abs(X).max(axis=0), SolverSettings())
    final, l2 = wp.state_errors(X * np.array([1.0, 1.01]), ref)
    assert final == pytest.approx(np.sqrt(0.5 * 0.01**2))
    assert l2 == pytest.approx(np.sqrt((0.005**2 + 0.01**2) / 4))


def test_reference_is_cross_checked(small):
    _, ref = small
    check = ref.crosscheck
    assert check["method"] == "scipy_radau"
    assert 0 < check["error_l2"] < 1e-6
    assert ref.settings.rtol == wp.REFERENCE_RTOL


@pytest.mark.slow  # CVODES at 1e-12 and scipy Radau: some 3 s
def test_full_cross_check_runs_on_resting_velocities():
    """The vent scene (n = 1, to 0.3 s: 0.1 s at rest, velocities at 0, then venting) at
    the full run's cross-check tolerance: scipy Radau at atol 1e-15 took more than
    20 000 steps in the first 15 ms of rest (the full run stopped: too many steps); at
    CHECK_ATOL_MIN it takes some 5 000 in all and agrees with the CVODES reference."""
    sc = dataclasses.replace(wp.scenarios(1)["vent"], t_final=0.3, n_out=31)
    ref = wp.reference(sc, wp.FULL.check_rtol)
    assert ref.crosscheck["rtol"] == wp.FULL.check_rtol
    assert ref.crosscheck["atol"] == wp.CHECK_ATOL_MIN
    assert ref.crosscheck["n_steps"] < 20_000, ref.crosscheck
    assert ref.crosscheck["error_l2"] < 1e-10, ref.crosscheck


def test_sweep_records_and_error_falls_with_tolerance(small):
    sc, ref = small
    started = time.perf_counter()
    recs = wp.sweep(sc, ref, TINY, only=["cvodes", "scipy_radau", "rk4"])
    elapsed = time.perf_counter() - started
    assert len(recs) == 3 + 3 + 2
    keys = {"scenario", "method", "kind", "rtol", "atol", "step_s", "status", "error_final"}
    keys |= {"error_l2", "wall_time_s", "n_steps", "n_rhs", "n_jac"}
    for r in recs:
        assert r["status"] == "ok", r
        assert keys <= set(r)
    for method in ("cvodes", "scipy_radau", "rk4"):
        errs = [r["error_l2"] for r in recs if r["method"] == method]
        assert errs[-1] < errs[0] / 10, (method, errs)
    # each record's time is a measured share of the sweep (a median of repeats or one run)
    walls = [r["wall_time_s"] for r in recs]
    assert min(walls) > 0 and sum(walls) <= elapsed, (walls, elapsed)
    cvodes = [r for r in recs if r["method"] == "cvodes"]
    assert all(r["atol"] == pytest.approx(r["rtol"] * wp.ATOL_PER_RTOL) for r in cvodes)


def test_wall_at_error_interpolates_log_log():
    recs = [
        {
            "method": "m",
            "status": "ok",
            "rtol": 1e-4,
            "step_s": None,
            "error_l2": 1e-4,
            "wall_time_s": 1.0,
        },
        {
            "method": "m",
            "status": "ok",
            "rtol": 1e-8,
            "step_s": None,
            "error_l2": 1e-8,
            "wall_time_s": 100.0,
        },
        {"method": "m", "status": "failed", "rtol": 1e-9, "step_s": None},
    ]
    assert wp.wall_at_error(recs, "m", 1e-6) == pytest.approx(10.0)
    assert wp.wall_at_error(recs, "m", 1e-10) is None


def test_vent_scenario_slackens_the_threads():
    sc = wp.scenarios(3)["vent"]
    res = sc.run(SolverSettings(rtol=1e-8, atol=1e-11), all_signals=True)
    stretch = [
        res[n].min() for n in res.names if n.startswith("myofibril.actin") and n.endswith(".e")
    ]
    assert min(stretch) < 0


def test_plot_writes_a_small_png(small, tmp_path):
    sc, ref = small
    recs = wp.sweep(sc, ref, TINY, only=["cvodes"])
    path = wp.plot(recs, sc, ref, tmp_path / "wp.png")
    assert path.exists() and 0 < path.stat().st_size < 200_000


@dataclasses.dataclass(frozen=True)
class _Comparator:
    """The PWM command as one continuous expression of time (no breakpoints): what an
    integrator that steps across the edges would see (the library refuses this law)."""

    duty: float
    period: float
    delay: float

    def __call__(self, t):
        s = np.asarray(t) - self.delay
        return np.where((s >= 0) & (np.mod(s, self.period) < self.duty * self.period), 1.0, 0.0)

    def casadi(self, t):
        import casadi as cs

        s = t - self.delay
        on = cs.logic_and(s >= 0, cs.fmod(s, self.period) < self.duty * self.period)
        return cs.if_else(on, 1.0, 0.0)


@pytest.mark.slow  # a 1e-12 reference through 20 PWM edges: some 3 s
def test_pwm_scenario_stepping_across_edges_fails_stopping_at_them_converges():
    """On the PWM valve (issue 26): rk4 stopping at every edge (the simulator's
    breakpoints) against rk4 stepping across them (the command as one expression of
    time, integrated by the method directly): at the same step the second's error is
    first order in the step (each edge's position within a step is lost), the first's
    far smaller; CVODES at rtol 1e-8 is within 1e-5 of the reference."""
    from sarcomere.dynamics.simulation.settings import METHODS, InputLaw, Segment, segment_w

    sc = dataclasses.replace(
        wp.scenarios(1)["pwm"], t_final=0.2, n_out=21, command=Step(initial=0.3, final=0.3)
    )
    ref = wp.reference(sc, 1e-7)
    model, x0 = sc.setup()
    plan = wp.Plan(
        tolerances=(1e-8,), steps={"rk4": (1.3e-4,)}, repeats=1, budget_s=0.0, check_rtol=1e-7
    )
    recs = {r["method"]: r for r in wp.sweep(sc, ref, plan, ["cvodes", "rk4"])}
    assert recs["cvodes"]["error_l2"] < 1e-5
    stopping = recs["rk4"]["error_l2"]
    # the same rk4 over the whole run, the command a continuous law: no edge is a breakpoint
    pwm = model.modulators["valve.cmd"]
    law = InputLaw((_Comparator(0.3, pwm.period, pwm.delay),))
    settings = SolverSettings("rk4", step=1.3e-4, options=(("on_unstable", "ignore"),))
    seg = Segment(
        model,
        settings,
        model.parameters(),
        law,
        segment_w(0.0, sc.t_final),
        0.0,
        x0,
        np.zeros(0),
        sc.t_out[1:],
        {},
    )
    X, _ = METHODS["rk4"].run(seg)
    crossing = wp.state_errors(np.vstack([x0, X]), dataclasses.replace(ref))[1]
    assert crossing > 20 * stopping, (crossing, stopping)


@pytest.mark.slow  # compiles rodas and radau for the one-unit chain
def test_rodas_is_on_the_chart_and_its_error_falls_with_tolerance(small):
    """The Rosenbrock method is one of the chart's adaptive methods; on the step scene
    its error falls with the tolerance as radau's does, within 10x of radau's at each."""
    sc, ref = small
    assert "rodas" in wp.ADAPTIVE
    recs = wp.sweep(sc, ref, TINY, only=["rodas", "radau"])
    assert [r["status"] for r in recs] == ["ok"] * 6, recs
    errs = {m: [r["error_l2"] for r in recs if r["method"] == m] for m in ("rodas", "radau")}
    assert errs["rodas"][0] > 100 * errs["rodas"][-1], errs
    for a, b in zip(errs["rodas"], errs["radau"], strict=True):
        assert a < 10 * b + 1e-9, errs
