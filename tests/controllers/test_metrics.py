"""Scene metrics against closed forms: the tension-bound violation and the settling time
of a step judged fairly for a controller that previews the reference."""

import math

import numpy as np
import pytest

from sarcomere.controllers.metrics import (
    SETTLING_BAND,
    loop_metrics,
    loop_status,
    step_response_metrics,
    step_window_end,
    tension_violation,
)
from sarcomere.dynamics.errors import ParameterError


def test_tension_violation_of_a_sine_dipping_below_the_bound():
    """The lower thread ``T = 0.2 + a cos(2 pi f t)`` N, the other always taut: the deepest
    violation is ``a``; the thread is more than ``tol`` below the bound for the fraction
    ``arccos(tol / a) / pi`` of each period."""
    a, f, tol, dt = 0.05, 2.0, 1e-3, 1e-5
    t = np.arange(0, 3 / f, dt)  # three periods
    low = 0.2 + a * np.cos(2 * np.pi * f * t)
    got = tension_violation(np.vstack([low, np.full_like(t, 0.4)]), 0.2, dt, tol)
    assert got["tension_violation_max_mN"] == pytest.approx(a * 1e3, rel=1e-9)
    exact = 3 / f * math.acos(tol / a) / math.pi
    assert got["tension_violation_time_s"] == pytest.approx(exact, abs=6 * 2 * dt)
    # a thread riding the bound a few uN below it violates by that much, for no time
    riding = tension_violation(np.full((1, 100), 0.2 - 5e-6), 0.2, 0.01)
    assert riding["tension_violation_max_mN"] == pytest.approx(5e-3)
    assert riding["tension_violation_time_s"] == 0
    # above the bound: nothing
    assert tension_violation(np.full((2, 10), 0.3), 0.2, 0.01) == {
        "tension_violation_max_mN": 0.0,
        "tension_violation_time_s": 0.0,
    }


def _previewed_step(t, t_step, tau, t_next, lead):
    """A first-order response to a unit step at ``t_step`` [s] (time constant ``tau``) that
    starts ramping towards the next reference change at ``t_next - lead``, as an MPC that
    sees ``lead`` seconds ahead does."""
    y = np.where(t >= t_step, 1 - np.exp(-(t - t_step) / tau), 0.0)
    return y + np.where(t >= t_next - lead, 2.0 * (t - (t_next - lead)), 0.0)


def test_settling_time_of_a_previewing_controller_is_judged_before_its_preview():
    dt, t_step, tau, t_next, lead = 1e-3, 0.5, 0.1, 2.0, 0.2
    t = np.arange(0, 3, dt)
    y = _previewed_step(t, t_step, tau, t_next, lead)
    exact = tau * math.log(1 / SETTLING_BAND)  # exp(-s / tau) = 2 %: 0.391 s
    end = step_window_end(t_step, t_next, lead)
    assert end == pytest.approx(t_next - lead)
    fair = step_response_metrics(t, y, 0.0, 1.0, t_step, end)
    assert fair["settling_time_s"] == pytest.approx(exact, abs=dt)
    # judged up to the next change itself, the move made on purpose reads as not settled
    blind = step_response_metrics(t, y, 0.0, 1.0, t_step, step_window_end(t_step, t_next))
    assert blind["settling_time_s"] == pytest.approx(t_next - t_step)
    # an unforeseen event (a disturbance) ends the window whatever the preview
    assert step_window_end(t_step, t_next, lead, t_unforeseen=1.2) == 1.2
    # the same response without the move: both windows give the closed form
    calm = np.where(t >= t_step, 1 - np.exp(-(t - t_step) / tau), 0.0)
    for window in (end, t_next):
        got = step_response_metrics(t, calm, 0.0, 1.0, t_step, window)
        assert got["settling_time_s"] == pytest.approx(exact, abs=dt)


def test_a_window_that_ends_before_the_step_is_refused():
    with pytest.raises(ParameterError, match="step_time"):
        step_window_end(0.5, 0.6, 0.2)  # the next change is within the preview of the step
    with pytest.raises(ParameterError, match="preview_s"):
        step_window_end(0.5, 2.0, -0.1)


def test_loop_metrics_names_and_units():
    t = np.arange(0, 1, 0.01)
    m = loop_metrics(
        "m",
        t,
        1e-3 * np.ones_like(t),
        np.zeros_like(t),
        np.full((2, 100), 0.19),
        [1e-3, 3e-3],
        None,
        tension_min=0.2,
    )
    assert m["rmse_mm"] == pytest.approx(1.0)
    assert m["tension_violation_max_mN"] == pytest.approx(10.0)
    assert m["tension_violation_time_s"] == pytest.approx(1.0)
    assert m["solve_time_median_ms"] == pytest.approx(2.0)


def test_loop_status_names_limit_cycles_divergence_and_all_fallback():
    """The status of a run from its error alone (issue 24: a limit cycle was reported as
    an ordinary row): a decaying error is "ok", a sustained oscillation of 5 times the
    motion asked for a "limit cycle", a growing one "diverged", and a run that fell back on
    every sample "all fallback"; a disturbance starts a new window, judged on its own tail."""
    t = np.arange(0, 10, 0.01)
    r = np.where(t >= 0.5, -1e-3, 0.0)  # the motion asked for: 1 mm
    settled = r + 1e-3 * np.exp(-t / 0.2) * np.cos(9 * t)
    assert loop_status(t, settled, r, [], 0.04) == ("ok", "")
    cycle = r + 5e-3 * np.sin(2 * np.pi * 1.3 * t)
    status, why = loop_status(t, cycle, r, [], 0.04, unit="m")
    assert status == "limit cycle" and "7.5-10 s" in why and "changing sign" in why, why
    growing = r + 1e-4 * np.exp(t / 1.5) * np.sin(2 * np.pi * 1.3 * t)
    assert loop_status(t, growing, r, [], 0.04)[0] == "diverged"
    drifting = r + 0.004 * t  # away for good, no oscillation
    assert loop_status(t, drifting, r, [], 0.04)[0] == "diverged"
    # a 10 mm kick at 6 s that is recovered from by the end: ok; held to the end: not
    kicked = settled + np.where(t >= 6, 1e-2 * np.exp(-(t - 6) / 0.3), 0.0)
    assert loop_status(t, kicked, r, [6.0], 0.04)[0] == "ok"
    late = settled + np.where(t >= 6, 1e-2 * np.exp(-(t - 6) / 30), 0.0)
    assert loop_status(t, late, r, [6.0], 0.04)[0] == "diverged"
    assert loop_status(t, settled, r, [], 0.04, fallbacks=len(t))[0] == "all fallback"
    # a regulation run (no motion asked for) is judged against 2 % of the reachable range
    still = np.zeros_like(t)
    assert loop_status(t, still + 5e-4 * np.sin(9 * t), still, [], 0.04)[0] == "ok"
    assert loop_status(t, still + 5e-3 * np.sin(9 * t), still, [], 0.04)[0] == "limit cycle"
