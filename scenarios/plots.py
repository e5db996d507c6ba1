"""PNG figures of run results: one figure per group of signals sharing a unit.

Files hold SI; figures show readable units (kPa, mm, deg, g). Figures are drawn on the
Agg canvas directly, without pyplot, so no global matplotlib state is touched.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from sarcomere.dynamics.results import Result

#: SI unit -> (display unit, factor from SI to display).
DISPLAY_UNITS: Mapping[str, tuple[str, float]] = {
    "Pa": ("kPa", 1e-3),
    "m": ("mm", 1e3),
    "rad": ("deg", 180.0 / math.pi),
    "kg": ("g", 1e3),
    "m^3": ("cm^3", 1e6),
    "kg/s": ("g/s", 1e3),
    "1": ("-", 1.0),
}

#: SI unit -> name of the quantity, used to name the default groups.
QUANTITIES: Mapping[str, str] = {
    "N": "force",
    "Pa": "pressure",
    "m": "length",
    "rad": "angle",
    "kg": "mass",
    "s": "time",
    "1": "ratio",
    "m^3": "volume",
    "kg/s": "mass_flow",
}


def display(unit: str) -> tuple[str, float]:
    """Display unit and factor for an SI ``unit`` (unchanged if not in the table)."""
    return DISPLAY_UNITS.get(unit, (unit, 1.0))


def groups_by_unit(result: Result, names: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """Group ``names`` of ``result`` by unit; a group is named after its quantity."""
    groups: dict[str, list[str]] = {}
    for name in names:
        unit = result.units[name]
        group = QUANTITIES.get(unit, re.sub(r"[^A-Za-z0-9]+", "_", unit))
        groups.setdefault(group, []).append(name)
    return {g: tuple(n) for g, n in groups.items()}


def plot_groups(
    results: Mapping[str, Result],
    groups: Mapping[str, Sequence[str]],
    out_dir: Path,
    title: str,
) -> list[Path]:
    """Draw one figure per group into ``out_dir/plot_<group>.png``.

    Parameters
    ----------
    results : mapping of str to Result
        Curves to draw; with several results each curve is labelled with its key.
    groups : mapping of str to sequence of str
        Group name -> signals sharing one unit.
    out_dir : pathlib.Path
    title : str
        Figure title prefix (the scenario name).

    Returns
    -------
    list of pathlib.Path
    """
    first = next(iter(results.values()))
    x_unit, x_scale = display(first.index_unit)
    paths = []
    for group, names in groups.items():
        y_unit, y_scale = display(first.units[names[0]])
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # lazy: CLI start-up
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 4.4), layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        for key, result in results.items():
            for name in names:
                label = name if len(results) == 1 else f"{key}: {name}" if len(names) > 1 else key
                ax.plot(result.index * x_scale, result[name] * y_scale, label=label)
        ax.set_xlabel(f"{first.index_name} [{x_unit}]")
        ax.set_ylabel(f"{group.replace('_', ' ')} [{y_unit}]")
        ax.set_title(f"{title}: {group.replace('_', ' ')}")
        ax.grid(True, alpha=0.3)
        if len(results) * len(names) > 1:
            ax.legend()
        path = out_dir / f"plot_{group}.png"
        fig.savefig(path, dpi=120)
        paths.append(path)
    return paths
