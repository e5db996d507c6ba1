"""The definition of one named metric, shared by the study parser and the metrics (a
module of its own so neither imports the other)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MetricDef:
    """A named scalar per sample: unit (SI) and long name; ``signal``/``time`` for a value
    at a named time."""

    name: str
    unit: str
    long_name: str
    signal: str = ""
    time: float | None = None
