"""Closed-loop metrics: tracking error, step response, constraints, solve times.

Every function takes plain arrays in SI and returns floats; :func:`loop_metrics` puts
them under the names the scenes report (prefixed there by the controller's key).

Examples
--------
>>> import numpy as np
>>> t = np.linspace(0, 1, 101)
>>> step_response_metrics(t, 1 - np.exp(-t / 0.1), 0.0, 1.0, 0.0, 1.0)["overshoot_pct"]
0.0
"""

from __future__ import annotations

import math

import numpy as np

from sarcomere.dynamics.errors import ParameterError

SETTLING_BAND = 0.02
"""Settling: the error stays within this fraction of the step size."""

VIOLATION_TOL = 1e-3
"""Tension-bound violation [N] below which a sample does not count as violating in
:func:`tension_violation`'s time: 1 mN, the tolerance issue 18 gives a constrained MPC for
its estimator's error (a controller riding the bound reads a few uN below it)."""

UNIT_SCALES = {"m": (1e-3, "mm"), "N": (1.0, "N"), "Pa": (1e3, "kPa")}
"""How a tracked output's error is reported: SI unit -> (scale, suffix)."""


def rmse(y: np.ndarray, r: np.ndarray) -> float:
    """Root-mean-square of ``y - r`` [their unit]."""
    return float(np.sqrt(np.mean((np.asarray(y) - np.asarray(r)) ** 2)))


def step_window_end(
    t_step: float, t_next_reference: float, preview_s: float = 0.0, t_unforeseen: float = math.inf
) -> float:
    """End of the window [s] in which a reference step at ``t_step`` is judged.

    The window ends at the next change of the reference, ``t_next_reference``, less the
    controller's preview horizon ``preview_s`` (a controller that sees the reference that
    far ahead starts moving for the next change then, on purpose: that move is not a
    failure to settle), or at ``t_unforeseen`` (a disturbance, the end of the run: things
    no controller sees coming), whichever is first. Without preview (``preview_s = 0``)
    every controller is judged up to the next event, as before.

    Raises
    ------
    ParameterError
        ``preview_s`` < 0, or a window that would end at or before the step (the next
        change of the reference comes within the preview horizon of the step).
    """
    if not (math.isfinite(preview_s) and preview_s >= 0):
        raise ParameterError("preview_s", preview_s, "[0, inf) s")
    end = min(t_next_reference - preview_s, t_unforeseen)
    if not end > t_step:
        raise ParameterError(
            "step_time",
            t_step,
            f"< {end:g} s: the step is judged up to the next reference change at "
            f"{t_next_reference:g} s less the preview horizon {preview_s:g} s, or the next "
            f"unforeseen event at {t_unforeseen:g} s",
        )
    return end


def step_response_metrics(
    t: np.ndarray, y: np.ndarray, r_before: float, r_after: float, t_step: float, t_end: float
) -> dict[str, float]:
    """Overshoot [%] and 2 % settling time [s] of a reference step at ``t_step``, judged
    on the samples in ``[t_step, t_end)`` (``t_end`` from :func:`step_window_end`).

    Overshoot is the largest excursion beyond the new reference, against the step size
    (0 if none). Settling time is from the step to the first sample after which the
    error stays within :data:`SETTLING_BAND` of the step size up to ``t_end``; a
    response that has not settled by then gets ``t_end - t_step`` (a lower bound).
    """
    t, y = np.asarray(t), np.asarray(y)
    keep = (t >= t_step) & (t < t_end)
    tw, yw = t[keep], y[keep]
    size = r_after - r_before
    if size == 0 or len(tw) == 0:
        return {"overshoot_pct": 0.0, "settling_time_s": 0.0}
    beyond = np.sign(size) * (yw - r_after)
    overshoot = max(0.0, float(beyond.max()) / abs(size) * 100)
    outside = np.abs(yw - r_after) > SETTLING_BAND * abs(size)
    if not outside.any():
        settle = 0.0
    elif outside[-1]:
        settle = t_end - t_step
    else:
        last = int(np.flatnonzero(outside)[-1])
        settle = float(tw[last + 1] - t_step)
    return {"overshoot_pct": overshoot, "settling_time_s": settle}


def tension_violation(
    tensions: np.ndarray, tension_min: float, dt: float, tol: float = VIOLATION_TOL
) -> dict[str, float]:
    """How far and how long the plant's thread tensions broke ``T >= tension_min``.

    ``tensions`` [N] is threads x samples, sampled every ``dt`` [s]. Returns
    ``tension_violation_max_mN``: the largest ``tension_min - T`` over threads and samples
    [mN] (0 if none), and ``tension_violation_time_s``: ``dt`` times the number of samples
    at which some thread is more than ``tol`` [N] below the bound (each sample stands for
    the ``dt`` after it). The bounds of the command hold by construction
    (:meth:`~.base.Controller.checked`): the tension is the one state bound to check.
    """
    T = np.atleast_2d(np.asarray(tensions, dtype=float))
    if T.size == 0:
        return {"tension_violation_max_mN": 0.0, "tension_violation_time_s": 0.0}
    slack = tension_min - T.min(axis=0)  # the worst thread at each sample
    return {
        "tension_violation_max_mN": max(0.0, float(slack.max())) * 1e3,
        "tension_violation_time_s": float(np.count_nonzero(slack > tol)) * dt,
    }


def solve_times(times_s: list[float]) -> dict[str, float]:
    """Median and 95th percentile of the controller's update times [ms]."""
    if not times_s:
        return {"solve_time_median_ms": 0.0, "solve_time_p95_ms": 0.0}
    ms = np.asarray(times_s) * 1e3
    return {
        "solve_time_median_ms": float(np.median(ms)),
        "solve_time_p95_ms": float(np.percentile(ms, 95)),
    }


FAILED_ERROR = 1.0
"""A window fails when the RMS tracking error over its last quarter exceeds this multiple
of the motion asked for (:func:`loop_status`): healthy runs of the packaged scenes stay
below 0.13 of it, the LQI's limit cycle at n = 8 under the rate limit is 6 times it."""

REACH_FLOOR = 0.02
"""The motion asked for is at least this fraction of the reachable output range (a
regulation run whose reference never moves is judged against it)."""


def loop_status(
    t: np.ndarray,
    y: np.ndarray,
    r: np.ndarray,
    events: list[float],
    reach_span: float,
    fallbacks: int = 0,
    unit: str = "",
) -> tuple[str, str]:
    """Whether a closed-loop run did its job: ``(status, reason)`` with status ``"ok"``,
    ``"all fallback"`` (the controller's own method failed on every sample), ``"limit
    cycle"`` or ``"diverged"`` (reason: empty for "ok", else what was seen, and when).

    The run is cut into windows at the unforeseen ``events`` (a disturbance); each window
    is judged on its last quarter (after the transients a controller may take): it fails
    when the RMS of ``y - r`` there exceeds :data:`FAILED_ERROR` times the motion asked
    for (the reference's peak-to-peak over the run, at least :data:`REACH_FLOOR` of the
    reachable range ``reach_span``). A failed window whose error changes sign at least
    4 times (counting only excursions beyond half its RMS, not the noise) and does not
    grow (its RMS at most twice that of the quarter before) is a limit cycle; any other
    failure is a divergence. The first failed window is reported.
    """
    t, e = np.asarray(t, dtype=float), np.asarray(y, dtype=float) - np.asarray(r, dtype=float)
    if len(t) and fallbacks >= len(t):
        return "all fallback", f"the controller fell back on all {len(t)} samples"
    scale = max(float(np.ptp(r)) if len(t) else 0.0, REACH_FLOOR * reach_span)
    end = float(t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.0)) if len(t) else 0.0
    edges = [0.0, *sorted(x for x in events if 0 < x < end), end]
    for a, b in zip(edges[:-1], edges[1:], strict=False):
        tail = (t >= a + 0.75 * (b - a) - 1e-9) & (t < b)
        before = (t >= a + 0.5 * (b - a) - 1e-9) & (t < a + 0.75 * (b - a) - 1e-9)
        if not tail.any() or scale <= 0:
            continue
        rms = float(np.sqrt(np.mean(e[tail] ** 2)))
        if rms <= FAILED_ERROR * scale:
            continue
        signs = np.sign(e[tail][np.abs(e[tail]) > 0.5 * rms])
        crossings = int(np.count_nonzero(np.diff(signs)))
        growing = before.any() and rms > 2 * float(np.sqrt(np.mean(e[before] ** 2)))
        seen = (
            f"RMS error {rms:.3g} {unit} over {a + 0.75 * (b - a):.3g}-{b:.3g} s, "
            f"{rms / scale:.3g} times the motion asked for ({scale:.3g} {unit})"
        )
        if crossings >= 4 and not growing:
            return "limit cycle", f"{seen}, changing sign {crossings} times"
        return "diverged", seen + (", growing" if growing else "")
    return "ok", ""


def loop_metrics(
    unit: str,
    t: np.ndarray,
    y: np.ndarray,
    r: np.ndarray,
    tensions: np.ndarray,
    times_s: list[float],
    step: tuple[float, float, float, float] | None = None,
    tension_min: float = 0.0,
    dt: float | None = None,
) -> dict[str, float]:
    """The scene metrics of one run: ``rmse_<suffix>`` (:data:`UNIT_SCALES`),
    ``overshoot_pct`` and ``settling_time_s`` (of ``step`` = ``(r_before, r_after,
    t_step, t_end)``, ``t_end`` the window's end, 0 without one), the
    :func:`tension_violation` (sampled every ``dt``, default ``t[1] - t[0]``) and the
    solve times."""
    scale, suffix = UNIT_SCALES.get(unit, (1.0, unit))
    out = {f"rmse_{suffix}": rmse(y, r) / scale}
    if step is None:
        out.update({"overshoot_pct": 0.0, "settling_time_s": 0.0})
    else:
        out.update(step_response_metrics(t, y, *step))
    if dt is None:
        dt = float(t[1] - t[0]) if len(t) > 1 else 0.0
    out.update(tension_violation(tensions, tension_min, dt))
    out.update(solve_times(times_s))
    return out
