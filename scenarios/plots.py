"""PNG figures of run results: one figure per group of signals sharing a unit and magnitude.

Files hold SI; figures show readable units (kPa, mm, deg, g). Figures are drawn on the
Agg canvas directly, without pyplot, so no global matplotlib state is touched (and a run
never imports pyplot). Long curves are drawn as their per-pixel envelope: a million-point
run plots as fast as a thousand-point one.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

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


#: Axes position in the 6.4 x 4.4 in figure (fractions): room for 8-character tick labels,
#: the axis labels and the title.
MARGINS = {"left": 0.14, "right": 0.97, "bottom": 0.11, "top": 0.93}

#: Most curves one figure draws; more are thinned to evenly spaced ones (first and last kept).
MAX_CURVES = 8

#: Signals of one unit share an axis only within this ratio of magnitudes.
MAGNITUDE_RATIO = 20.0

#: Line styles and markers cycled so identical curves stay visible on top of each other.
STYLES = ("-", "--", ":", "-.")
MARKERS = ("", "o", "s", "^", "v", "D", "x", "+")


#: Pixel columns a figure is drawn at (6.4 in at 120 dpi is 768): a longer curve is drawn
#: as the minimum and maximum of each column (:func:`envelope`), which looks the same.
PLOT_COLUMNS = 1000


def envelope(x: np.ndarray, y: np.ndarray, columns: int = PLOT_COLUMNS):
    """``(x, y)`` thinned to the first, the last, and the minimum and maximum of each of
    ``columns`` equal runs of samples, in their order: every peak and dip stays.

    Examples
    --------
    >>> y = np.zeros(10_000); y[4321] = 1.0
    >>> x2, y2 = envelope(np.arange(10_000.0), y, 100)
    >>> len(x2) <= 202, float(y2.max()), float(x2[np.argmax(y2)]), float(x2[0]), float(x2[-1])
    (True, 1.0, 4321.0, 0.0, 9999.0)
    """
    n = len(x)
    if n <= 2 * columns:
        return x, y
    starts = np.linspace(0, n, columns + 1).astype(int)[:-1]
    lo = np.array([a + np.argmin(y[a:b]) for a, b in zip(starts, [*starts[1:], n], strict=True)])
    hi = np.array([a + np.argmax(y[a:b]) for a, b in zip(starts, [*starts[1:], n], strict=True)])
    keep = np.unique(np.concatenate([[0, n - 1], lo, hi]))
    return x[keep], y[keep]


def groups_by_unit(result: Result, names: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """Group ``names`` of ``result`` by unit and magnitude; a group is named after its
    quantity (``length``), further groups of the same unit at a smaller magnitude get a
    number (``length_2``): 110 mm and 1 mm signals do not share an axis."""
    by_unit: dict[str, list[str]] = {}
    for name in names:
        by_unit.setdefault(result.units[name], []).append(name)
    groups: dict[str, tuple[str, ...]] = {}
    for unit, members in by_unit.items():
        quantity = QUANTITIES.get(unit, re.sub(r"[^A-Za-z0-9]+", "_", unit))
        size = {n: float(np.max(np.abs(result[n]), initial=0.0)) for n in members}
        ordered = sorted(members, key=lambda n: -size[n])
        bands: list[list[str]] = []
        for name in ordered:
            if bands and size[name] * MAGNITUDE_RATIO >= size[bands[-1][0]]:
                bands[-1].append(name)
            else:
                bands.append([name])
        for k, band in enumerate(bands):
            keep = tuple(n for n in members if n in band)  # in the caller's order
            groups[quantity if k == 0 else f"{quantity}_{k + 1}"] = keep
    return groups


def thin(items: Sequence, count: int) -> list:
    """At most ``count`` of ``items``, evenly spaced, the first and the last kept.

    Examples
    --------
    >>> thin(list(range(10)), 3)
    [0, 4, 9]
    """
    if len(items) <= count:
        return list(items)
    picks = np.unique(np.round(np.linspace(0, len(items) - 1, count)).astype(int))
    return [items[i] for i in picks]


def _distinct_curves(
    results: Mapping[str, Result], names: Sequence[str]
) -> list[tuple[list[str], str]]:
    """``(result keys, signal)`` per distinct curve: a signal identical in several results
    (a shared reference) is one curve, labelled with every key that holds it."""
    curves: list[tuple[list[str], str]] = []
    for name in names:
        for key, result in results.items():
            same = next(
                (
                    c
                    for c in curves
                    if c[1] == name
                    and np.array_equal(results[c[0][0]].index, result.index)
                    and np.array_equal(results[c[0][0]][name], result[name])
                ),
                None,
            )
            if same is None:
                curves.append(([key], name))
            else:
                same[0].append(key)
    return curves


def plot_groups(
    results: Mapping[str, Result],
    groups: Mapping[str, Sequence[str]],
    out_dir: Path,
    title: str,
) -> list[Path]:
    """Draw one figure per group into ``out_dir/plot_<group>.png``.

    A figure draws at most :data:`MAX_CURVES` curves: with more signals or results, evenly
    spaced ones (first, middle, last, ...) and its title says how many of how many.

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

        fig = Figure(figsize=(6.4, 4.4))
        fig.subplots_adjust(**MARGINS)  # fixed: constrained layout cost 40 % of the drawing
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        curves = _distinct_curves(results, names)
        total = len(curves)
        drawn = thin(curves, MAX_CURVES)
        for k, (keys, name) in enumerate(drawn):
            result = results[keys[0]]
            owner = ", ".join(keys) if len(keys) < len(results) else "all"
            label = name if len(results) == 1 else f"{owner}: {name}" if len(names) > 1 else owner
            x, y = envelope(result.index * x_scale, result[name] * y_scale)
            ax.plot(
                x,
                y,
                label=label,
                linestyle=STYLES[k % len(STYLES)],
                marker=MARKERS[k % len(MARKERS)],
                markevery=max(1, len(x) // 12),
                markersize=4,
            )
        ax.set_xlabel(f"{first.index_name} [{x_unit}]")
        quantity = re.sub(r"_\d+$", "", group).replace("_", " ")  # length_2 -> length
        ax.set_ylabel(f"{quantity} [{y_unit}]")
        count = len(drawn)
        note = f" ({count} of {total} curves)" if count < total else ""
        ax.set_title(f"{title}: {group.replace('_', ' ')}{note}")
        ax.grid(True, alpha=0.3)
        if count > 1:
            ax.legend(fontsize="small")
        path = out_dir / f"plot_{group}.png"
        fig.savefig(path, dpi=120)
        paths.append(path)
    return paths
