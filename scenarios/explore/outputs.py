"""What a study leaves beside its store: the figures of :mod:`.plots` and ``summary.json``.

``summary.json`` (SI units, each number with its unit; ``null`` where a value is undefined):

* ``study``, ``kind``, ``base``, ``method``, ``seed``, ``parameter_sources`` (when the
  scene includes a parameter file: each parameter's source), ``fingerprint``, ``results`` (a
  digest of the results it was written from: a re-run that changed nothing redraws
  nothing), ``version``;
* ``samples``: ``total``, ``ok``, ``failed`` (status 1), ``worker_lost`` (status 2),
  ``not_computed`` (status -1), ``errors`` (the messages of the samples that are not ok,
  grouped by the message with its numbers as ``#``: the count, the first message and the
  first samples of each kind), ``failures`` (the first :data:`LISTED_FAILURES` of them with
  their factor values) and ``notes`` (the commonest notes of ok samples: why a metric is
  undefined there);
* ``metrics``: per metric ``unit``, ``count`` (ok samples with a value), ``undefined`` (ok
  samples without one), ``median``, ``p05``, ``p95`` and ``min``/``max`` each with the
  factor values (``at``) where they occur;
* ``series``: per time series the median and 5-95 % band of its final value;
* ``sensitivity`` (sensitivity studies): the method, blocks used and the factors of each
  metric ranked by total index (Sobol') or mu* (Morris), or ``refused`` with the reason;
* ``plots``: the figure files written; ``warnings``: anything the reader must know.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..catalog import version
from . import analysis, plots

if TYPE_CHECKING:  # pragma: no cover
    import xarray as xr

#: Failed samples listed with their factor values in ``summary.json``.
LISTED_FAILURES = 20
#: Samples listed per kind of failure or note in ``summary.json``.
LISTED_SAMPLES = 5
#: Most common notes of ok samples (why a metric is undefined) listed in ``summary.json``.
LISTED_NOTES = 10
#: Status codes of the store (interface file) and their names in ``summary.json``.
STATUS_NAMES = {0: "ok", 1: "failed", 2: "worker_lost", -1: "not_computed"}


def _num(value: Any) -> float | None:
    """A JSON number, None for NaN or infinity."""
    v = float(value)
    return v if math.isfinite(v) else None


def _flat_factors(ds: xr.Dataset, study: Any, like: xr.DataArray) -> dict[str, np.ndarray]:
    """Each factor's value per element of ``like`` (grid coordinates broadcast), flat."""
    out = {}
    for factor in study.factors:
        if factor.name in ds.variables:
            values = ds[factor.name].broadcast_like(like).transpose(*like.dims).values
            out[factor.name] = np.asarray(values, dtype=float).ravel()
    return out


def _at(factors: dict[str, np.ndarray], i: int) -> dict[str, float | None]:
    return {name: _num(values[i]) for name, values in factors.items()}


_NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def grouped(messages) -> list[dict[str, Any]]:
    """``(sample, message)`` pairs grouped by the message with its numbers as ``#`` (one
    kind of failure at several times or values is one entry): each with its count, the
    first message and the first :data:`LISTED_SAMPLES` samples, commonest first.

    >>> [g["message"] for g in grouped([(3, "step too small at t = 0.3 s"), (5, "t = 1e-2")])]
    ['step too small at t = # s', 't = #']
    """
    groups: dict[str, dict[str, Any]] = {}
    for i, message in messages:
        key = _NUMBER.sub("#", message)
        group = groups.setdefault(key, {"message": key, "count": 0, "example": message})
        group["count"] += 1
        group.setdefault("samples", [])
        if len(group["samples"]) < LISTED_SAMPLES:
            group["samples"].append(int(i))
    return sorted(groups.values(), key=lambda g: -g["count"])


def sample_counts(ds: xr.Dataset, study: Any) -> dict[str, Any]:
    """Counts of the samples by status, the distinct errors and the first failures."""
    status = np.asarray(ds["status"].values).ravel()
    counts: dict[str, Any] = {"total": int(status.size)}
    counts |= {name: int(np.sum(status == code)) for code, name in STATUS_NAMES.items()}
    errors = np.asarray(ds["error"].values, dtype=object).ravel() if "error" in ds else None
    bad = np.flatnonzero(status != 0)
    text = (lambda i: str(errors[i])) if errors is not None else (lambda i: "")
    counts["errors"] = grouped((i, text(i)) for i in bad)
    noted = [] if errors is None else np.flatnonzero(status == 0)
    counts["notes"] = grouped((i, text(i)) for i in noted if text(i))[:LISTED_NOTES]
    factors = _flat_factors(ds, study, ds["status"])
    counts["failures"] = [
        {
            "sample": int(i),
            "status": STATUS_NAMES.get(int(status[i]), str(int(status[i]))),
            "error": str(errors[i]) if errors is not None else "",
            "at": _at(factors, i),
        }
        for i in bad[:LISTED_FAILURES]
    ]
    return counts


def metric_summary(ds: xr.Dataset, study: Any, metric: str) -> dict[str, Any]:
    """Median, 5/95 % and the extremes (with their factor values) over the ok samples."""
    da = ds[metric]
    values = np.asarray(da.where(ds["status"] == 0).values, dtype=float).ravel()
    finite = np.flatnonzero(np.isfinite(values))
    out: dict[str, Any] = {
        "unit": plots.unit_of(ds, study, metric),
        "count": int(finite.size),
        "undefined": plots.undefined(ds, metric),
    }
    if finite.size == 0:
        return out | {k: None for k in ("median", "p05", "p95", "min", "max")}
    p05, median, p95 = np.percentile(values[finite], plots.BAND)
    factors = _flat_factors(ds, study, da)
    lo, hi = finite[np.argmin(values[finite])], finite[np.argmax(values[finite])]
    return out | {
        "median": _num(median),
        "p05": _num(p05),
        "p95": _num(p95),
        "min": {"value": _num(values[lo]), "sample": int(lo), "at": _at(factors, lo)},
        "max": {"value": _num(values[hi]), "sample": int(hi), "at": _at(factors, hi)},
    }


def series_summary(ds: xr.Dataset, study: Any, variable: str) -> dict[str, Any]:
    """Median and 5-95 % band of a time series' final value over the ok samples."""
    final = ds[variable].where(ds["status"] == 0).isel(time=-1).values.ravel()
    final = final[np.isfinite(final)]
    band = np.percentile(final, plots.BAND) if final.size else [math.nan] * 3
    return {
        "unit": plots.unit_of(ds, study, variable),
        "time": _num(ds["time"].values[-1]),
        "final": {"p05": _num(band[0]), "median": _num(band[1]), "p95": _num(band[2])},
    }


def sensitivity_summary(result: xr.Dataset) -> dict[str, Any]:
    """The analysis' method, blocks and ranked factors per metric (JSON-ready)."""
    out: dict[str, Any] = {
        "method": result.attrs["method"],
        "conf_level": result.attrs["conf_level"],
        "blocks_total": int(result.attrs["blocks_total"]),
        "failed_samples": json.loads(result.attrs["failed_samples"]),
        "metrics": {},
    }
    for metric in result["metric"].values:
        out["metrics"][str(metric)] = {
            "blocks_used": int(result["blocks_used"].sel(metric=metric)),
            "note": str(result["note"].sel(metric=metric).values),
            "unit": "1"
            if out["method"] == "sobol"
            else str(result["metric_unit"].sel(metric=metric).values),
            "ranked": analysis.ranked(result, str(metric)),
        }
    return out


def _figures(ds: xr.Dataset, study: Any, folder: Path, summary: dict, draw: bool) -> list[Path]:
    """The figures of the study (drawn when ``draw``), and its sensitivity analysis into
    ``summary`` (also without figures)."""
    metrics = [m.name for m in study.metrics if m.name in ds]
    drawn: list[Path | None] = []
    if study.kind == "grid" and draw:
        for metric in metrics:
            path = plots.design_map(ds, study, metric, folder) or plots.design_line(
                ds, study, metric, folder
            )
            if path is None:
                summary["warnings"].append(
                    f"no map of {metric}: no grid axis varies or no ok sample has a value"
                )
            drawn.append(path)
    elif study.kind == "sample" and draw:
        drawn.append(plots.histograms(ds, study, metrics, folder))
    elif study.kind == "sensitivity":
        try:
            result = analysis.analyse(ds, study)
        except analysis.AnalysisError as err:
            summary["sensitivity"] = {"refused": str(err)}
            summary["warnings"].append(f"sensitivity analysis refused: {err}")
        else:
            summary["sensitivity"] = sensitivity_summary(result)
            bars = plots.sobol_bars if result.attrs["method"] == "sobol" else plots.morris_plane
            drawn.append(bars(result, study.name, folder) if draw else None)
    curves = plots.grid_curves if study.kind == "grid" else plots.envelope
    for variable in (v for v in ds.data_vars if str(v).startswith("series_") and draw):
        drawn.append(curves(ds, study, str(variable), folder))
    return [p for p in drawn if p is not None]


def results_digest(ds: xr.Dataset, fingerprint: str, draw: bool) -> str:
    """SHA-256 of the results (every variable's values) and of what is written from them:
    equal digests, equal figures and ``summary.json``."""
    h = hashlib.sha256(f"{fingerprint} plots={draw}".encode())
    for name in sorted(map(str, ds.variables)):
        values = ds[name].values
        h.update(name.encode())
        h.update(
            "\0".join(map(str, values.ravel())).encode()
            if values.dtype == object
            else values.tobytes()
        )
    return h.hexdigest()


def _previous(folder: Path) -> dict:
    """The earlier ``summary.json`` in ``folder`` ({} if none or unreadable)."""
    try:
        old = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return {}
    return old if isinstance(old, dict) else {}


def _remove_previous(folder: Path, old: dict) -> None:
    """Delete the figures an earlier summary (``old``) lists (a resumed study may draw
    other ones), nothing else."""
    names = old.get("plots", [])
    for name in names if isinstance(names, list) else []:
        path = folder / str(name)
        if path.suffix == ".png" and path.parent == folder and path.is_file():
            path.unlink()


def write_outputs(
    ds: xr.Dataset, study: Any, folder: Path, *, draw: bool = True, force: bool = False
) -> dict[str, Any]:
    """Write the study's figures and ``summary.json`` into ``folder``; return the summary.
    Nothing is written when the summary there is of the same results (its ``results``
    digest) and its figures are all there, unless ``force``.

    Parameters
    ----------
    ds : xarray.Dataset
        The study's results (interface file: grid axes or a ``sample`` dimension, metric
        variables, ``status``, ``error``, attributes ``fingerprint``, ``version``, ...).
    study : StudyDef
        The study definition the results belong to.
    folder : pathlib.Path
        Where to write (created if missing), beside the store.
    draw : bool
        Draw the figures (else only ``summary.json``, with the sensitivity analysis).
    force : bool
        Write even when nothing changed.

    Returns
    -------
    dict
        The content of ``summary.json`` (module docstring).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fingerprint = ds.attrs.get("fingerprint") or study.fingerprint()
    digest = results_digest(ds, fingerprint, draw)
    old = _previous(folder)
    there = all((folder / str(name)).is_file() for name in old.get("plots", []))
    if old.get("results") == digest and there and not force:
        return old
    _remove_previous(folder, old)
    design = study.design()
    summary: dict[str, Any] = {
        "study": study.name,
        "kind": study.kind,
        "base": study.base,
        "fidelity": study.fidelity,
        "method": ds.attrs.get("method", design.method),
        "seed": study.seed,
        **({"parameter_sources": src} if (src := study.scene().parameter_sources()) else {}),
        "fingerprint": fingerprint,
        "results": digest,
        "version": ds.attrs.get("version") or version(),
        "samples": sample_counts(ds, study),
        "metrics": {
            m.name: metric_summary(ds, study, m.name) for m in study.metrics if m.name in ds
        },
        "series": {
            str(v).removeprefix("series_"): series_summary(ds, study, str(v))
            for v in ds.data_vars
            if str(v).startswith("series_")
        },
        "warnings": [],
    }
    samples = summary["samples"]
    if samples["ok"] < samples["total"]:
        summary["warnings"].append(
            f"{samples['total'] - samples['ok']} of {samples['total']} samples are not ok "
            f"({samples['failed']} failed, {samples['worker_lost']} worker lost, "
            f"{samples['not_computed']} not computed): left out of every statistic and figure"
        )
    summary["plots"] = [p.name for p in _figures(ds, study, folder, summary, draw)]
    text = json.dumps(summary, indent=2, allow_nan=False)
    (folder / "summary.json").write_text(text + "\n", encoding="utf-8")
    return summary
