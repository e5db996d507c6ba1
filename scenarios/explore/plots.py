"""PNG figures of a study's results: design maps, Monte Carlo envelopes and histograms,
Sobol' bars and the Morris mu*/sigma plane.

Values are SI in the Dataset and shown in readable units (:func:`..plots.display`: kPa, mm,
g). Samples whose ``status`` is not 0 are left out of every figure and counted in its
title. Figures are drawn on the Agg canvas without pyplot (as :mod:`..plots`), and
matplotlib is imported only when a figure is drawn.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sarcomere.scenarios.plots import DISPLAY_UNITS, STYLES, thin

if TYPE_CHECKING:  # pragma: no cover
    import xarray as xr

#: Display units of the study quantities beyond :data:`..plots.DISPLAY_UNITS`.
STUDY_UNITS: Mapping[str, tuple[str, float]] = {
    **DISPLAY_UNITS,
    "m^2": ("mm^2", 1e6),
    "m2": ("mm^2", 1e6),
    "kg/(s*Pa)": ("g/(s kPa)", 1.0),
}
#: Most facets one design map draws (evenly spaced levels of the facet axis beyond).
MAX_FACETS = 6
#: Percentiles of the Monte Carlo bands and of the summaries, %.
BAND = (5.0, 50.0, 95.0)
#: Sample curves drawn thinly behind an envelope.
SAMPLE_CURVES = 8
#: Bins of a metric histogram; most levels of a discrete factor stacked in one.
HIST_BINS = 30
MAX_GROUPS = 8
#: A metric whose spread is below this fraction of its median is drawn as a constant.
CONSTANT_RTOL = 1e-6
#: Factor names preferred as a design map's facet rather than an axis (few levels).
FACET_FIRST = ("n", "family")
DPI = 110


def display(unit: str) -> tuple[str, float]:
    """Display unit and factor from SI for ``unit`` (unchanged if not in the table)."""
    return STUDY_UNITS.get(unit, (unit, 1.0))


def unit_of(ds: xr.Dataset, study: Any, name: str) -> str:
    """SI unit of a factor, metric or series: the variable's ``unit`` attribute, else the
    study's factor or metric of that name, else (a series) the model signal's unit."""
    if name in ds.variables and ds[name].attrs.get("unit"):
        return str(ds[name].attrs["unit"])
    for item in (*study.factors, *study.metrics):
        if item.name == name:
            return str(item.unit)
    if name.startswith("series_"):
        from .spec import signal_unit

        return signal_unit(study, name.removeprefix("series_"))
    return "1"


def label(ds: xr.Dataset, study: Any, name: str) -> str:
    """Axis label ``name [display unit]``."""
    return f"{name} [{display(unit_of(ds, study, name))[0]}]"


def undefined(ds: xr.Dataset, name: str) -> int:
    """Samples that ran (status 0) where ``name`` has no value (a rise time of a run that
    does not move: the sample's ``error`` says why)."""
    values = np.asarray(ds[name].values, dtype=float)
    ok = np.broadcast_to(np.asarray(ds["status"].values) == 0, ds["status"].shape)
    axes = tuple(range(ok.ndim, values.ndim))  # a series: undefined anywhere in time
    return int(np.sum(ok & np.isnan(values).any(axis=axes)))


def status_note(ds: xr.Dataset, *names: str) -> str:
    """``"k of N samples ok, m failed or missing (left out)"`` from the ``status``
    variable, and for each of ``names`` the ok samples where it is undefined."""
    status = np.asarray(ds["status"].values).ravel()
    ok, total = int(np.sum(status == 0)), status.size
    note = f"{ok} of {total} samples ok"
    if ok < total:
        note += f", {total - ok} failed or missing (left out)"
    gaps = [f"{name} undefined in {k}" for name in names if (k := undefined(ds, name))]
    return note + "".join(f"; {g}" for g in gaps)


def _figure(panels: int, width: float = 4.6, height: float = 3.6, cols: int = 3):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    cols = max(1, min(cols, panels))
    rows = math.ceil(panels / cols)
    fig = Figure(figsize=(width * cols + 0.6, height * rows + 0.7), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[panels:]:
        ax.set_visible(False)
    return fig, axes[:panels]


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path


def _ok(ds: xr.Dataset, name: str) -> xr.DataArray:
    """``ds[name]`` with the samples whose status is not 0 set to NaN."""
    return ds[name].where(ds["status"] == 0)


# --------------------------------------------------------------------------------------
# Design maps
# --------------------------------------------------------------------------------------
def paper_points() -> list[tuple[str, str, list[dict[str, float]]]]:
    """The paper's operating points as ``(label, marker, [factor values, SI])``: the
    concentric experiment (n = 3, loads 0-100 g, 0-0.1 MPa) and the isometric one
    (n = 1, 2, 3 at 0.1 MPa, no load: a fixed length)."""
    from sarcomere.dynamics.calibration import CONCENTRIC_LOADS_KG, CONCENTRIC_PRESSURES_PA
    from sarcomere.dynamics.paper_reported import REPORTED

    concentric = [
        {"n": 3.0, "load": m, "pressure": p}
        for m in CONCENTRIC_LOADS_KG
        for p in CONCENTRIC_PRESSURES_PA
    ]
    p_iso = float(REPORTED["isometric_pressure_Pa"])  # type: ignore[arg-type]
    isometric = [{"n": float(n), "pressure": p_iso} for n in REPORTED["isometric_force_N"]]  # type: ignore[union-attr]
    return [
        ("paper: concentric tests (n = 3)", "o", concentric),
        ("paper: isometric tests", "s", isometric),
    ]


def _map_axes(da: xr.DataArray) -> tuple[str, str, str | None, dict[str, Any]]:
    """(x, y, facet or None, fixed {dim: value}) of a design map of ``da``: the axes with
    the most levels (``n`` and ``family`` last), facets on the next, the rest fixed at
    their middle level."""
    varying = [d for d in da.dims if da.sizes[d] > 1]
    order = sorted(
        varying, key=lambda d: (d in FACET_FIRST, -da.sizes[d], d != "pressure", varying.index(d))
    )
    x, y = order[0], order[1]
    facet = order[2] if len(order) > 2 else None
    rest = [d for d in da.dims if d not in (x, y, facet)]
    fixed = {d: da[d].values[da.sizes[d] // 2] for d in rest}
    return x, y, facet, fixed


def _marks(ax, ds, study, x: str, y: str, where: Mapping[str, float], xs, ys) -> None:
    """The paper's points on a (x, y) panel: those with both values inside the panel's
    range whose other grid values match the panel's (``where``)."""
    sx, sy = display(unit_of(ds, study, x))[1], display(unit_of(ds, study, y))[1]
    span = [(float(np.min(v)), float(np.max(v))) for v in (xs, ys)]
    for text, marker, points in paper_points():
        pts = [
            (p[x], p[y])
            for p in points
            if x in p
            and y in p
            and all(
                math.isclose(p.get(d, v), v, rel_tol=1e-9, abs_tol=1e-12) for d, v in where.items()
            )
            and all(
                lo - 1e-12 <= val <= hi + 1e-12
                for val, (lo, hi) in zip((p[x], p[y]), span, strict=True)
            )
        ]
        if pts:
            px, py = np.array(pts).T
            ax.plot(px * sx, py * sy, marker, mfc="none", mec="black", ms=7, ls="", label=text)


def _contour_panel(ax, ds, study, da, failed, x, y, levels, where):
    """Filled contours of ``da`` (2-D over x, y; NaN where failed or undefined) on ``ax``;
    the failed samples (``failed``: a mask like ``da``) and undefined values marked."""
    (_, sx), (_, sy) = display(unit_of(ds, study, x)), display(unit_of(ds, study, y))
    scale = display(unit_of(ds, study, da.name))[1]
    z = da.transpose(y, x).values * scale
    xs, ys = ds[x].values.astype(float), ds[y].values.astype(float)
    gx, gy = np.meshgrid(xs * sx, ys * sy)
    filled = ax.contourf(gx, gy, np.ma.masked_invalid(z), levels=levels, cmap="viridis")
    ax.contour(gx, gy, np.ma.masked_invalid(z), levels=levels, colors="white", linewidths=0.4)
    ax.plot(
        gx.ravel(),
        gy.ravel(),
        "o",
        ms=2.5,
        mfc="white",
        mec="0.2",
        mew=0.4,
        ls="",
        label="grid point",
    )
    lost = failed.transpose(y, x).values
    gap = ~np.isfinite(z) & ~lost
    for mask, mark, color, mew, what in (
        (lost, "x", "red", 1.5, "failed sample"),
        (gap, "+", "0.2", 1.2, "undefined value"),
    ):
        if mask.any():
            ax.plot(gx[mask], gy[mask], mark, color=color, ms=7, mew=mew, label=what, clip_on=False)
    _marks(ax, ds, study, x, y, where, xs, ys)
    ax.set_xlabel(label(ds, study, x))
    ax.set_ylabel(label(ds, study, y))
    return filled


def _figure_legend(fig, axes) -> None:
    """One legend below the panels with each label once (markers of any panel)."""
    entries: dict[str, Any] = {}
    for ax in axes:
        for handle, text in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(text, handle)
    if entries:
        fig.legend(
            entries.values(),
            entries.keys(),
            loc="outside lower center",
            ncols=len(entries),
            fontsize="small",
        )


def _value_text(ds, study, name: str, value) -> str:
    unit, scale = display(unit_of(ds, study, name))
    return f"{name} = {float(value) * scale:.4g} {unit}".replace(" -", "")


def _levels(lo: float, hi: float) -> np.ndarray:
    """About 12 contour levels at round values covering [lo, hi]."""
    from matplotlib.ticker import MaxNLocator

    if not hi > lo:
        hi = lo + max(abs(lo), 1.0) * 1e-6
    return MaxNLocator(12).tick_values(lo, hi)


def design_map(ds: xr.Dataset, study: Any, metric: str, folder: Path) -> Path | None:
    """Contours of ``metric`` over the two grid axes with the most levels, faceted over a
    third, further axes at their middle level; the paper's operating points marked.
    ``folder/map_<metric>.png``; None when fewer than two grid axes vary."""
    da = _ok(ds, metric)
    if sum(da.sizes[d] > 1 for d in da.dims) < 2:
        return None
    x, y, facet, fixed = _map_axes(da)
    da, failed = da.sel(fixed), (ds["status"] != 0).broadcast_like(da).sel(fixed)
    facets = thin(list(da[facet].values), MAX_FACETS) if facet else [None]
    finite = da.values[np.isfinite(da.values)]
    unit, scale = display(unit_of(ds, study, metric))
    if finite.size == 0:
        return None
    lo, hi = float(finite.min()) * scale, float(finite.max()) * scale
    levels = _levels(lo, hi)
    fig, axes = _figure(len(facets))
    for ax, value in zip(axes, facets, strict=True):
        where = {d: float(v) for d, v in fixed.items()}
        panel, lost = da, failed
        if facet is not None:
            panel, lost = da.sel({facet: value}), failed.sel({facet: value})
            where[facet] = float(value)
            ax.set_title(_value_text(ds, study, facet, value), fontsize="medium")
        filled = _contour_panel(ax, ds, study, panel, lost, x, y, levels, where)
    fig.colorbar(filled, ax=list(axes), label=f"{metric} [{unit}]", format="%.4g")
    _figure_legend(fig, axes)
    shown = (
        f" ({len(facets)} of {da.sizes[facet]} {facet} levels)"
        if facet and len(facets) < da.sizes[facet]
        else ""
    )
    fixed_text = "".join(f"; {_value_text(ds, study, d, v)}" for d, v in fixed.items())
    fig.suptitle(
        f"{study.name}: {metric}{shown}{fixed_text}\n{status_note(ds, metric)}", fontsize="medium"
    )
    return _save(fig, folder / f"map_{metric}.png")


def design_line(ds: xr.Dataset, study: Any, metric: str, folder: Path) -> Path | None:
    """``metric`` against the one grid axis that varies (a grid of one axis):
    ``folder/map_<metric>.png``; None when no axis varies."""
    da = _ok(ds, metric)
    varying = [d for d in da.dims if da.sizes[d] > 1]
    if len(varying) != 1:
        return None
    x = varying[0]
    fig, (ax,) = _figure(1, 6.0, 4.2)
    sx = display(unit_of(ds, study, x))[1]
    sy = display(unit_of(ds, study, metric))[1]
    ax.plot(ds[x].values * sx, da.squeeze().values * sy, "o-")
    ax.set_xlabel(label(ds, study, x))
    ax.set_ylabel(label(ds, study, metric))
    ax.grid(True, alpha=0.3)
    fig.suptitle(f"{study.name}: {metric}\n{status_note(ds, metric)}", fontsize="medium")
    return _save(fig, folder / f"map_{metric}.png")


def _curve_axes(dims: Sequence[str], sizes: Mapping[str, int]):
    """(colour, style or None, facet or None) axes of a grid's curves: the axis with the
    most levels as colour (``n``, ``family`` last, ``pressure`` first among equals)."""
    varying = [d for d in dims if sizes[d] > 1]
    order = sorted(
        varying, key=lambda d: (d in FACET_FIRST, -sizes[d], d != "pressure", varying.index(d))
    )
    order += [None] * (3 - len(order))
    return order[0], order[1], order[2]


def grid_curves(ds: xr.Dataset, study: Any, variable: str, folder: Path) -> Path | None:
    """The time series ``variable`` of every grid point: colour = the axis with the most
    levels, line style = the next (at most 4 levels), panels = a third (at most 6), further
    axes at their middle level: ``folder/curves_<signal>.png``."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    da = _ok(ds, variable)
    dims = [d for d in da.dims if d != "time"]
    colour, style, facet = _curve_axes(dims, da.sizes)
    if colour is None:
        return None
    fixed = {d: da[d].values[da.sizes[d] // 2] for d in dims if d not in (colour, style, facet)}
    da = da.sel(fixed)
    signal = variable.removeprefix("series_")
    unit, scale = display(unit_of(ds, study, variable))
    t_unit, t_scale = display(ds["time"].attrs.get("unit", "s"))
    c_scale = display(unit_of(ds, study, colour))[1]
    c_values = da[colour].values.astype(float) * c_scale
    norm, cmap = Normalize(c_values.min(), c_values.max()), colormaps["viridis"]
    styles = thin(list(da[style].values), len(STYLES)) if style else [None]
    facets = thin(list(da[facet].values), MAX_FACETS) if facet else [None]
    fig, axes = _figure(len(facets), 4.8, 3.8)
    t = ds["time"].values * t_scale
    for ax, f_value in zip(axes, facets, strict=True):
        panel = da.sel({facet: f_value}) if facet else da
        for k, s_value in enumerate(styles):
            lines = panel.sel({style: s_value}) if style else panel
            for c_value, c_shown in zip(da[colour].values, c_values, strict=True):
                y = lines.sel({colour: c_value}).values * scale
                ax.plot(t, y, color=cmap(norm(c_shown)), ls=STYLES[k], lw=1.2)
            if style:
                ax.plot(
                    [], [], color="0.3", ls=STYLES[k], label=_value_text(ds, study, style, s_value)
                )
        if facet:
            ax.set_title(_value_text(ds, study, facet, f_value), fontsize="medium")
        ax.set_xlabel(f"time [{t_unit}]")
        ax.set_ylabel(f"{signal} [{unit}]")
        ax.grid(True, alpha=0.3)
    fig.colorbar(ScalarMappable(norm, cmap), ax=list(axes), label=label(ds, study, colour))
    _figure_legend(fig, axes)
    fixed_text = "".join(f"; {_value_text(ds, study, d, v)}" for d, v in fixed.items())
    fig.suptitle(
        f"{study.name}: {signal}{fixed_text}\n{status_note(ds, variable)}", fontsize="medium"
    )
    return _save(fig, folder / f"curves_{signal}.png")


# --------------------------------------------------------------------------------------
# Monte Carlo
# --------------------------------------------------------------------------------------
def _flat(ds: xr.Dataset, name: str) -> np.ndarray:
    """Values of ``name`` with status 0, one row per sample (time last for series)."""
    da = _ok(ds, name)
    other = [d for d in da.dims if d != "time"]
    values = da.transpose(*other, ...).values.reshape(
        -1, *([da.sizes["time"]] if "time" in da.dims else [])
    )
    keep = np.isfinite(values).all(axis=-1) if values.ndim > 1 else np.isfinite(values)
    return values[keep]


def envelope(ds: xr.Dataset, study: Any, variable: str, folder: Path) -> Path | None:
    """Median and 5-95 % band of the time series ``variable`` (``series_<signal>``) over
    the ok samples, a few samples drawn thinly behind: ``folder/envelope_<signal>.png``."""
    values = _flat(ds, variable)
    if len(values) == 0:
        return None
    signal = variable.removeprefix("series_")
    unit, scale = display(unit_of(ds, study, variable))
    t_unit, t_scale = display(ds["time"].attrs.get("unit", "s"))
    t = ds["time"].values * t_scale
    lo, mid, hi = np.percentile(values * scale, BAND, axis=0)
    fig, (ax,) = _figure(1, 6.4, 4.2)
    for k, row in enumerate(thin(list(values), SAMPLE_CURVES)):
        ax.plot(
            t,
            row * scale,
            color="0.6",
            lw=0.6,
            ls=STYLES[k % len(STYLES)],
            label="samples" if k == 0 else None,
        )
    ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.3, label=f"{BAND[0]:g}-{BAND[2]:g} %")
    ax.plot(t, mid, color="tab:blue", lw=2, label="median")
    ax.set_xlabel(f"time [{t_unit}]")
    ax.set_ylabel(f"{signal} [{unit}]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    fig.suptitle(f"{study.name}: {signal}\n{status_note(ds, variable)}", fontsize="medium")
    return _save(fig, folder / f"envelope_{signal}.png")


def _grouping(ds: xr.Dataset, study: Any) -> str | None:
    """The discrete factor to stack histograms by (the calibration family, a ``levels``
    factor) when there is exactly one with at most :data:`MAX_GROUPS` levels."""
    found = [
        f.name
        for f in study.factors
        if f.kind == "discrete" and 1 < len(f.values) <= MAX_GROUPS and f.name in ds
    ]
    return found[0] if len(found) == 1 else None


def _histogram(ax, ds, study, metric: str, group: str | None) -> None:
    unit, scale = display(unit_of(ds, study, metric))
    values = _ok(ds, metric).values.ravel() * scale
    keep = np.isfinite(values)
    if not keep.any():
        ax.text(0.5, 0.5, "no values", transform=ax.transAxes, ha="center")
        return
    lo, mid, hi = np.percentile(values[keep], BAND)
    spread = float(np.ptp(values[keep]))
    if spread <= CONSTANT_RTOL * max(abs(mid), 1e-300):
        text = f"constant: {mid:.6g} {unit}\n(spread {spread:.2g} {unit})"
        ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center")
        ax.set_xticks([])
        ax.set_yticks([])
        return
    bins = np.linspace(values[keep].min(), values[keep].max(), HIST_BINS + 1)
    if group is None:
        ax.hist(values[keep], bins=bins, color="tab:blue", alpha=0.75)
    else:
        levels = np.unique(ds[group].values[np.isfinite(ds[group].values)])
        factor = np.asarray(ds[group].broadcast_like(ds[metric]).values).ravel()
        stacks = [values[keep & (factor == v)] for v in levels]
        names = [_value_text(ds, study, group, v) for v in levels]
        ax.hist(stacks, bins=bins, stacked=True, label=names, alpha=0.85)
    for q, ls in zip((lo, mid, hi), (":", "-", ":"), strict=True):
        ax.axvline(q, color="black", ls=ls, lw=1)
    _plain_ticks(ax.xaxis)


def _plain_ticks(axis) -> None:
    """At most 5 ticks, full values (no offset such as ``1e-5 + 1.425e-2``)."""
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    axis.set_major_locator(MaxNLocator(5))
    axis.set_major_formatter(ScalarFormatter(useOffset=False))


def histograms(ds: xr.Dataset, study: Any, metrics: Sequence[str], folder: Path) -> Path | None:
    """One histogram per metric over the ok samples, median and 5/95 % marked, stacked by
    the study's discrete factor if it has one (:func:`_grouping`):
    ``folder/histograms.png``."""
    metrics = [m for m in metrics if m in ds]
    if not metrics:
        return None
    group = _grouping(ds, study)
    fig, axes = _figure(len(metrics), 4.2, 3.2)
    for ax, metric in zip(axes, metrics, strict=True):
        _histogram(ax, ds, study, metric, group)
        ax.set_xlabel(label(ds, study, metric))
        ax.set_ylabel("samples [count]")
        if gaps := undefined(ds, metric):
            ax.set_title(f"undefined in {gaps} ok samples", fontsize="small")
    _figure_legend(fig, axes[:1])
    stacked = f", stacked by {group}" if group else ""
    fig.suptitle(
        f"{study.name}: metrics (lines: median, {BAND[0]:g} and {BAND[2]:g} %{stacked})\n"
        f"{status_note(ds)}",
        fontsize="medium",
    )
    return _save(fig, folder / "histograms.png")


# --------------------------------------------------------------------------------------
# Sensitivity
# --------------------------------------------------------------------------------------
def _failed_text(result: xr.Dataset) -> str:
    """``"k of N samples failed or missing"`` of a sensitivity result (its blocks left out)."""
    failed = len(json.loads(result.attrs["failed_samples"]))
    total = result.attrs["blocks_total"] * result.attrs["block_size"]
    return f"{total - failed} of {total} samples ok" + (
        f", {failed} failed or missing (their blocks left out)" if failed else ""
    )


def _blocks_text(result: xr.Dataset, metric: str) -> str:
    used, total = int(result["blocks_used"].sel(metric=metric)), result.attrs["blocks_total"]
    note = str(result["note"].sel(metric=metric).values)
    note = note if len(note) <= 90 else note[:87] + "..."
    text = f"{used} of {total} blocks" + (
        f" ({total - used} with failed samples left out)" if used < total else ""
    )
    return f"{text}; {note}" if note else text


def sobol_bars(result: xr.Dataset, title: str, folder: Path) -> Path:
    """First-order and total Sobol' indices per factor with their confidence bars, one
    panel per metric: ``folder/sobol.png``."""
    metrics = list(result["metric"].values)
    factors = list(result["factor"].values)
    fig, axes = _figure(len(metrics), max(4.6, 0.55 * len(factors) + 1.5), 3.8, cols=2)
    pos = np.arange(len(factors))
    conf = int(round(100 * result.attrs["conf_level"]))
    for ax, metric in zip(axes, metrics, strict=True):
        row = result.sel(metric=metric)
        for k, (key, color) in enumerate((("S1", "tab:blue"), ("ST", "tab:orange"))):
            ax.bar(
                pos + (k - 0.5) * 0.38,
                row[key].values,
                0.38,
                yerr=row[f"{key}_conf"].values,
                capsize=3,
                color=color,
                label=f"{'first order' if key == 'S1' else 'total'} {key}",
            )
        ax.set_xticks(pos, factors, rotation=35, ha="right", fontsize="small")
        ax.axhline(0.0, color="black", lw=0.6)
        ax.set_ylabel("Sobol' index [-]")
        ax.set_title(f"{metric}: {_blocks_text(result, metric)}", fontsize="small")
        ax.legend(fontsize="x-small")
    fig.suptitle(
        f"{title}: Sobol' indices ({conf} % confidence bars)\n{_failed_text(result)}",
        fontsize="medium",
    )
    return _save(fig, folder / "sobol.png")


def morris_plane(result: xr.Dataset, title: str, folder: Path) -> Path:
    """Morris mu* against sigma per factor (mu* confidence as horizontal bars), one panel
    per metric: ``folder/morris.png``."""
    metrics = list(result["metric"].values)
    factors = list(result["factor"].values)
    fig, axes = _figure(len(metrics), 4.8, 4.0, cols=2)
    for ax, metric in zip(axes, metrics, strict=True):
        row = result.sel(metric=metric)
        unit, scale = display(str(row["metric_unit"].values))
        mu, sigma = row["mu_star"].values * scale, row["sigma"].values * scale
        ax.errorbar(mu, sigma, xerr=row["mu_star_conf"].values * scale, fmt="o", capsize=3)
        for name, a, b in zip(factors, mu, sigma, strict=True):
            ax.annotate(name, (a, b), textcoords="offset points", xytext=(4, 4), fontsize="x-small")
        top = float(np.nanmax(np.r_[mu, sigma, 0.0])) or 1.0
        ax.plot([0, top], [0, top], ":", color="0.5", lw=0.8, label="sigma = mu*")
        ax.set_xlabel(f"mu* of {metric} [{unit}]")
        ax.set_ylabel(f"sigma of {metric} [{unit}]")
        ax.set_title(_blocks_text(result, metric), fontsize="small")
        ax.legend(fontsize="x-small")
        ax.grid(True, alpha=0.3)
    fig.suptitle(
        f"{title}: Morris screening (effects over each factor's range)\n{_failed_text(result)}",
        fontsize="medium",
    )
    return _save(fig, folder / "morris.png")
