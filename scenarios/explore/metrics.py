"""Named scalar metrics of one transient run, and its time series on a stated grid.

The rise time and the overshoot are the scenes' own (:mod:`sarcomere.scenarios.step_metrics`,
with its noise threshold :data:`~sarcomere.scenarios.step_metrics.RISE_MIN_STROKE_M`); a metric a
run does not define (the rise time or overshoot of a run that does not move) is NaN with
the reason in the sample's note, never a silent NaN.
"""

from __future__ import annotations

import numpy as np

from ..step_metrics import RISE_MIN_STROKE_M, overshoot, rise_time
from .metric_def import MetricDef

LENGTH = "myofibril.length"

#: Metric name -> (SI unit, long name).
STANDARD = {
    "length_final": ("m", "final chain length"),
    "stroke": ("m", "stroke: initial minus final chain length (shortening > 0)"),
    "rise_time": ("s", "10-90 % rise time of the chain length"),
    "overshoot": ("1", "overshoot of the length past its final value, fraction of the stroke"),
    "peak_tension": ("N", "peak thread tension (every thread, whole run)"),
    "min_tension": ("N", "minimum thread tension (every thread, whole run)"),
    "air_mass": ("kg", "air mass added to the chambers, end minus start (every chamber)"),
    "peak_pressure": ("Pa", "peak chamber pressure, gauge (every chamber, whole run)"),
}


def value_at_metric(label: str, signal: str, time: float, unit: str) -> MetricDef:
    """A metric: ``signal`` at ``time`` [s] (linear interpolation on the output grid)."""
    return MetricDef(label, unit, f"{signal} at t = {time:g} s", signal, time)


def tensions(names) -> list[str]:
    """The thread tension signals among ``names``."""
    return [n for n in names if n.startswith("myofibril.actin") and n.endswith(".T")]


def pressures(names) -> list[str]:
    """The chamber pressure signals among ``names``."""
    return [n for n in names if n.endswith(".chamber.p_gauge")]


def chambers(names) -> list[str]:
    """The chamber air mass signals among ``names`` (one per unit at per-unit levels)."""
    return [n for n in names if n.endswith(".chamber.m_air")]


def metric_signals(name: str, signal_names) -> list[str]:
    """The signals standard metric ``name`` reads, among ``signal_names`` (empty: the
    model cannot give it)."""
    if name in ("peak_tension", "min_tension"):
        return tensions(signal_names)
    if name == "peak_pressure":
        return pressures(signal_names)
    if name == "air_mass":
        return chambers(signal_names)
    return [LENGTH] if LENGTH in signal_names else []


def needed_signals(signal_names, metrics, series) -> list[str]:
    """The model signals the metrics and series read (a subset of ``signal_names``)."""
    want = []
    for m in metrics:
        want += [m.signal] if m.signal else metric_signals(m.name, signal_names)
    if series is not None:
        want += list(series.signals)
    return list(dict.fromkeys(w for w in want if w in signal_names))


def compute(res, metrics) -> tuple[dict[str, float], list[str]]:
    """Each metric of ``res`` (a Result) by name, and notes on those left NaN (why)."""
    out, notes = {}, []
    t = np.asarray(res.index, float)
    L = np.asarray(res[LENGTH], float) if LENGTH in res else np.full(2, np.nan)
    for m in metrics:
        if m.signal:
            out[m.name] = float(np.interp(m.time, t, np.asarray(res[m.signal], float)))
        elif m.name == "length_final":
            out[m.name] = float(L[-1])
        elif m.name == "stroke":
            out[m.name] = float(L[0] - L[-1])
        elif m.name == "rise_time":
            rise, why = rise_time(t, L, RISE_MIN_STROKE_M, "m")
            out[m.name] = np.nan if rise is None else rise
            if rise is None:
                notes.append(f"rise_time: {why}")
        elif m.name == "overshoot":
            value, why = overshoot(L, RISE_MIN_STROKE_M, "m")
            out[m.name] = np.nan if value is None else value
            if value is None:
                notes.append(f"overshoot: {why}")
        elif m.name in ("peak_tension", "min_tension"):
            T = np.array([res[n] for n in tensions(res.names)])
            out[m.name] = float(T.max() if m.name == "peak_tension" else T.min())
        elif m.name == "peak_pressure":
            out[m.name] = float(np.max([res[n] for n in pressures(res.names)]))
        elif m.name == "air_mass":
            out[m.name] = float(sum(res[n][-1] - res[n][0] for n in chambers(res.names)))
    return out, notes


def series_values(res, series) -> dict[str, np.ndarray]:
    """``series.signals`` of ``res`` interpolated (linearly) to ``series.time``."""
    t = np.asarray(res.index, float)
    grid = np.asarray(series.time, float)
    return {s: np.interp(grid, t, np.asarray(res[s], float)) for s in series.signals}
