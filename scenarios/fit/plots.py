"""A fit's plots: measured against fitted with a residual panel per time series, static
curves with the data points, each profile with its 95 % threshold, the correlation
matrix, and the held-out experiments' predictions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from sarcomere.dynamics.identification.uncertainty import CHI2_95

from .reference import output_unit, relative_label


def _figure(size=(7, 5)) -> Figure:
    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


def _experiment(result, name: str, record: dict, path: Path, title: str) -> None:
    bound = next(b for b in result.built.experiments if b.spec.name == name)
    signals = list(record)
    fig = _figure((8, 2.6 * len(signals) + 0.5))
    static = bound.spec.kind == "static"
    for i, s in enumerate(signals):
        r = record[s]
        unit = output_unit(bound.spec, bound.model, s)
        y, yh = np.array(r["data"]), np.array(r["prediction"])
        if static:
            ax = fig.add_subplot(len(signals), 1, i + 1)
            x = np.arange(1, len(y) + 1)
            xlabel = "steady state #"
            if bound.spec.inputs:
                col = bound.spec.inputs[0]
                x = bound.table.columns[col][1]
                xlabel = f"{col} [{bound.table.columns[col][0]}]"
            ax.plot(x, y, "o", label="measured")
            ax.plot(x, yh, "x-", label="fitted")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(f"{relative_label(bound.spec, s)} [{unit}]", fontsize=8)
            ax.legend(fontsize=7)
            continue
        t = bound.table.time[np.array(r["sample"], dtype=int)]
        ax = fig.add_subplot(2 * len(signals), 1, 2 * i + 1)
        ax.plot(t, y, ".", ms=2, label="measured")
        ax.plot(t, yh, "-", lw=1, label="model")
        ax.set_ylabel(f"{s}\n[{unit}]", fontsize=7)
        ax.legend(fontsize=7)
        ax2 = fig.add_subplot(2 * len(signals), 1, 2 * i + 2, sharex=ax)
        ax2.plot(t, y - yh, lw=0.7, color="C3")
        ax2.set_ylabel("residual", fontsize=7)
        ax2.set_xlabel("time [s]")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def draw(result, out: Path) -> None:
    """Every plot into ``out``."""
    for name, rec in result.metrics.items():
        verdict = ", ".join(f"{s}: fit {r['fit_percent']:.1f} %" for s, r in rec.items())
        _experiment(result, name, rec, out / f"fit-{name}.png", f"{name} (fitted): {verdict}")
    for name, rec in result.validation.items():
        if name == "error":
            continue
        verdict = ", ".join(f"{s}: fit {r['fit_percent']:.1f} %" for s, r in rec.items())
        _experiment(
            result, name, rec, out / f"validation-{name}.png", f"{name} (held out): {verdict}"
        )
    params = result.built.params
    if result.profiles:
        fig = _figure((4 * min(len(result.profiles), 3), 3.2 * ((len(result.profiles) + 2) // 3)))
        for j, (k, prof) in enumerate(result.profiles.items()):
            ax = fig.add_subplot(
                (len(result.profiles) + 2) // 3, min(len(result.profiles), 3), j + 1
            )
            ax.plot(prof.values, prof.rise, "o-", ms=3)
            ax.axhline(CHI2_95, color="C3", ls="--", lw=1, label="95 %")
            ax.axvline(result.solution.theta[k], color="k", lw=0.5)
            ax.set_xlabel(f"{params[k].name} [{params[k].unit}]", fontsize=7)
            ax.set_ylabel("chi2 - chi2_min", fontsize=7)
            ax.set_title(result.verdicts[k]["verdict"], fontsize=7)
            values = np.asarray(prof.values, dtype=float)
            if params[k].log and values.min() > 0 and values.max() > 10 * values.min():
                ax.set_xscale("log")  # a wide profile; a narrow one reads better linear
            else:
                ax.xaxis.set_major_locator(MaxNLocator(4))
            ax.tick_params(labelsize=7)
        fig.tight_layout()
        fig.savefig(out / "profiles.png", dpi=110)
    n = len(params)
    fig = _figure((1.2 * n + 3, 1.0 * n + 2.5))
    ax = fig.add_subplot()
    im = ax.imshow(result.fisher.correlation, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(n), [e.name for e in params], rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(n), [e.name for e in params], fontsize=7)
    for i in range(n):
        for j in range(n):
            c = result.fisher.correlation[i, j]
            ax.text(
                j,
                i,
                "nan" if not np.isfinite(c) else f"{c:.2f}",
                ha="center",
                va="center",
                fontsize=6,
            )
    fig.colorbar(im)
    ax.set_title("correlation of the estimates (Fisher)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "correlation.png", dpi=110)
