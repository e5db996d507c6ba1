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

import numpy as np

SETTLING_BAND = 0.02
"""Settling: the error stays within this fraction of the step size."""

UNIT_SCALES = {"m": (1e-3, "mm"), "N": (1.0, "N"), "Pa": (1e3, "kPa")}
"""How a tracked output's error is reported: SI unit -> (scale, suffix)."""


def rmse(y: np.ndarray, r: np.ndarray) -> float:
    """Root-mean-square of ``y - r`` [their unit]."""
    return float(np.sqrt(np.mean((np.asarray(y) - np.asarray(r)) ** 2)))


def step_response_metrics(
    t: np.ndarray, y: np.ndarray, r_before: float, r_after: float, t_step: float, t_end: float
) -> dict[str, float]:
    """Overshoot [%] and 2 % settling time [s] of a reference step at ``t_step``, judged
    on the samples in ``[t_step, t_end)``.

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


def constraint_violation(tensions: np.ndarray, tension_min: float = 0.0) -> float:
    """Largest violation of ``T >= tension_min`` over all threads and samples [N]; 0 if
    none (input bounds hold by construction: :meth:`~.base.Controller.checked`)."""
    if np.size(tensions) == 0:
        return 0.0
    return max(0.0, float(tension_min - np.min(tensions)))


def solve_times(times_s: list[float]) -> dict[str, float]:
    """Median and 95th percentile of the controller's update times [ms]."""
    if not times_s:
        return {"solve_time_median_ms": 0.0, "solve_time_p95_ms": 0.0}
    ms = np.asarray(times_s) * 1e3
    return {
        "solve_time_median_ms": float(np.median(ms)),
        "solve_time_p95_ms": float(np.percentile(ms, 95)),
    }


def loop_metrics(
    unit: str,
    t: np.ndarray,
    y: np.ndarray,
    r: np.ndarray,
    tensions: np.ndarray,
    times_s: list[float],
    step: tuple[float, float, float, float] | None = None,
    tension_min: float = 0.0,
) -> dict[str, float]:
    """The scene metrics of one run: ``rmse_<suffix>`` (:data:`UNIT_SCALES`),
    ``overshoot_pct`` and ``settling_time_s`` (of ``step`` = ``(r_before, r_after,
    t_step, t_end)``, 0 without one), ``constraint_violation_max`` [N] and the solve
    times."""
    scale, suffix = UNIT_SCALES.get(unit, (1.0, unit))
    out = {f"rmse_{suffix}": rmse(y, r) / scale}
    if step is None:
        out.update({"overshoot_pct": 0.0, "settling_time_s": 0.0})
    else:
        out.update(step_response_metrics(t, y, *step))
    out["constraint_violation_max"] = constraint_violation(tensions, tension_min)
    out.update(solve_times(times_s))
    return out
