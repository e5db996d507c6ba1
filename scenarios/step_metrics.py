"""Step metrics of a run, shared by the transient kind's ``summary.json`` and the design
studies' metrics (:mod:`.explore.metrics`): rise time, overshoot, and the transient's
final and initial values, each left out with the reason where a run does not define it.
"""

from __future__ import annotations

import math

import numpy as np

from sarcomere.dynamics.results import Result

#: Smallest net length stroke (|final - initial|, m) with a rise time: below it the
#: change is not told from numerical noise (rtol 1e-6 on a 0.1 m chain is 0.1 um); the
#: packaged steps and ramps move about 15 mm.
RISE_MIN_STROKE_M = 1e-5


def transient_metrics(res: Result) -> tuple[dict[str, float], dict[str, str]]:
    """Final and initial length and pressure, rise time, slack time, solver statistics;
    and the metrics left out, each with why (``rise_time_10_90_s`` of a run that does not
    move, or whose output grid does not resolve the rise)."""
    m, left_out = {}, {}
    if "myofibril.length" in res:
        L = res["myofibril.length"]
        m["length_initial_mm"] = float(L[0] * 1e3)
        m["length_final_mm"] = float(L[-1] * 1e3)
        rise, why = rise_time(res.index, L, RISE_MIN_STROKE_M, "m")
        if rise is None:
            left_out["rise_time_10_90_s"] = why
        else:
            m["rise_time_10_90_s"] = rise
    chamber = next(n for n in res.names if n.endswith(".chamber.p_gauge"))  # the top unit
    m["pressure_final_kPa"] = res.final(chamber) / 1e3
    if "sensor.f" in res:
        m["force_final_N"] = res.final("sensor.f")
    stretches = [n for n in res.names if n.endswith(".e") and ".actin" in n]
    if stretches:
        slack = np.any(np.array([res[n] < 0 for n in stretches]), axis=0)
        m["slack_time_s"] = float(np.sum(np.diff(res.index) * slack[:-1]))
    m["solver_steps"] = float(res.meta.get("n_steps", math.nan))
    return m, left_out


def rise_time(
    t: np.ndarray, y: np.ndarray, min_stroke: float, unit: str = ""
) -> tuple[float | None, str]:
    """10-90 % rise time [s] of ``y(t)`` from ``y[0]`` to ``y[-1]``, on the linearly
    interpolated signal: the first times ``y`` crosses ``y0 + 0.1 dy`` and ``y0 + 0.9 dy``
    (``dy = y[-1] - y[0]``), each interpolated between its two samples.

    Returns ``(None, why)`` when ``|dy| < min_stroke`` (``unit``: the signal's, for the
    message) or when both crossings fall in one sample interval (the grid does not
    resolve the rise); else ``(rise, "")``.
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    dy = y[-1] - y[0]
    if not abs(dy) >= min_stroke:
        return None, (
            f"the net stroke |final - initial| = {abs(dy):.3g} {unit} is below the noise "
            f"level {min_stroke:g} {unit}: no rise to time"
        )
    frac = (y - y[0]) / dy
    crossings = []
    for level in (0.1, 0.9):
        i = int(np.argmax(frac >= level))  # >= 1: frac[0] = 0; frac[-1] = 1 reaches it
        w = (level - frac[i - 1]) / (frac[i] - frac[i - 1])
        crossings.append((i, t[i - 1] + w * (t[i] - t[i - 1])))
    (i10, t10), (i90, t90) = crossings
    if i10 == i90:
        return None, (
            f"the output grid ({t[i90] - t[i90 - 1]:.3g} s there) does not resolve the rise: "
            "both crossings fall in one interval"
        )
    return float(t90 - t10), ""


def overshoot(y: np.ndarray, min_stroke: float, unit: str = "") -> tuple[float | None, str]:
    """Overshoot of ``y`` past its final value, as a fraction of the net stroke ``|y[-1] -
    y[0]|`` (0 when it never passes it). Returns ``(None, why)`` when the stroke is below
    ``min_stroke`` (``unit``: the signal's, for the message); else ``(overshoot, "")``."""
    y = np.asarray(y, float)
    dy = y[-1] - y[0]
    if not abs(dy) >= min_stroke:
        return None, f"the net stroke {abs(dy):.3g} {unit} is below the noise level"
    return float(max(0.0, np.max((y - y[-1]) * np.sign(dy))) / abs(dy)), ""
