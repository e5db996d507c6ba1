"""Global sensitivity of a study's metrics: Sobol' indices and Morris screening (SALib).

Both take the study's result Dataset (flat ``sample`` dimension, in the design's order)
and its :class:`~.spec.StudyDef`, and return an xarray Dataset indexed by ``metric`` and
``factor``: Sobol' first-order and total indices (``S1``, ``ST``, dimensionless) with
their bootstrap confidence half-widths, or Morris ``mu_star``, ``mu_star_conf``, ``sigma``
(and the signed ``mu``) in the metric's unit per factor range.

Failed samples. Saltelli and Morris estimators need complete blocks: one Saltelli block is
the ``2 D + 2`` (or ``D + 2``) evaluations that share a base row, one Morris block is a
trajectory of ``D + 1`` evaluations. A sample whose ``status`` is not 0 (or whose metric is
not finite) removes its whole block, and the indices are estimated from the complete
blocks only (SALib's estimators are means over blocks, so they stay consistent; if failures
depend on the factors the indices describe the region where the model ran). The number of
blocks used is returned per metric (``blocks_used``), the failed samples are listed in the
attributes; a metric with fewer than :data:`MIN_BLOCKS` complete blocks is refused (NaN
indices, its ``note`` names the failed samples), and if every metric is refused the
analysis raises :class:`AnalysisError` with that message. A metric that is constant over the design
has no variance to apportion: its indices are NaN and its ``note`` says so.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from sarcomere.dynamics.errors import SarcomereError

if TYPE_CHECKING:  # pragma: no cover
    import xarray as xr

#: Confidence level of the bootstrap intervals (two-sided).
CONF_LEVEL = 0.95
#: Bootstrap resamples for the confidence intervals.
NUM_RESAMPLES = 1000
#: Fewest complete blocks (Saltelli base rows or Morris trajectories) analysed.
MIN_BLOCKS = 4
#: Failed sample indices named in an error message before "...".
NAMED_FAILURES = 20


class AnalysisError(SarcomereError, ValueError):
    """A sensitivity analysis cannot be made from this dataset; says why and what is needed."""


def failed_samples(ds: xr.Dataset) -> np.ndarray:
    """Flat indices of the samples whose ``status`` is not 0 (failed, lost or not computed)."""
    return np.flatnonzero(np.asarray(ds["status"].values).ravel() != 0)


def _named(indices: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:NAMED_FAILURES])
    return shown + (", ..." if len(indices) > NAMED_FAILURES else "")


def _problem(study: Any) -> tuple[Any, dict]:
    design = study.design()
    problem = design.salib_problem
    if not problem:
        raise AnalysisError(
            f"study '{study.name}': design method '{design.method}' has no SALib problem; "
            "sensitivity analysis needs kind = 'sensitivity'"
        )
    return design, problem


def _option(study: Any, design: Any, names: tuple[str, ...]) -> Any:
    """A sensitivity setting: the design's ``salib_options`` (what the sampler used), else
    the study's ``options``; None if neither has any of ``names``."""
    for source in (getattr(design, "salib_options", None), dict(getattr(study, "options", ()))):
        for name in names:
            if source and source.get(name) is not None:
                return source[name]
    return None


def _declared_metrics(study: Any) -> list[str] | None:
    """``[study.sensitivity] metrics`` as the study's TOML text gives them, None if absent."""
    import tomllib

    text = getattr(study, "source_text", "")
    section = tomllib.loads(text).get("study", {}).get("sensitivity", {}) if text else {}
    return section.get("metrics")


def sensitivity_metrics(ds: xr.Dataset, study: Any) -> list[str]:
    """The metrics to analyse: ``[study.sensitivity] metrics``, else every study metric."""
    design = study.design()
    names = (
        _option(study, design, ("metrics",))
        or _declared_metrics(study)
        or [m.name for m in study.metrics]
    )
    missing = [n for n in names if n not in ds]
    if missing:
        raise AnalysisError(f"metrics {missing} are not in the dataset ({sorted(ds.data_vars)})")
    return list(names)


def _complete_blocks(ds: xr.Dataset, metric: str, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(values reshaped to blocks x size, mask of the complete blocks) of ``metric``."""
    y = np.asarray(ds[metric].values, dtype=float).ravel()
    ok = (np.asarray(ds["status"].values).ravel() == 0) & np.isfinite(y)
    blocks = y.reshape(-1, size)
    keep = ok.reshape(-1, size).all(axis=1)
    if keep.sum() < MIN_BLOCKS:
        bad = np.flatnonzero(~ok)
        raise AnalysisError(
            f"metric '{metric}': {int(keep.sum())} of {len(keep)} blocks of {size} samples are "
            f"complete, at least {MIN_BLOCKS} needed; {len(bad)} samples failed or have no "
            f"value: {_named(bad)}"
        )
    return blocks, keep


def _each_metric(ds: xr.Dataset, metrics: list[str], size: int, compute) -> tuple:
    """``compute(values of the complete blocks, their mask)`` per metric -> (blocks used,
    notes, results: None where refused or undefined). A metric with too few complete blocks
    is refused alone (its note says why); all of them refused raises."""
    used, notes, rows = np.zeros(len(metrics), dtype=int), [""] * len(metrics), []
    for i, metric in enumerate(metrics):
        try:
            blocks, keep = _complete_blocks(ds, metric, size)
        except AnalysisError as err:
            notes[i], row = f"refused: {err}", None
        else:
            used[i] = keep.sum()
            row, notes[i] = compute(blocks[keep].ravel(), keep)
        rows.append(row)
    if all(r is None for r in rows) and any(n.startswith("refused") for n in notes):
        raise AnalysisError("; ".join(n.removeprefix("refused: ") for n in notes))
    return used, notes, rows


def _block_size(n: int, size: int, what: str) -> None:
    if n % size:
        raise AnalysisError(
            f"{n} samples are not whole {what} of {size}: the dataset does not follow the design"
        )


def _result(
    names: list[str], metrics: list[str], ds: xr.Dataset, data: dict, attrs: dict
) -> xr.Dataset:
    import xarray as xr

    units = [ds[m].attrs.get("unit", "") for m in metrics]
    factor_units = [ds[f].attrs.get("unit", "") if f in ds else "" for f in names]
    coords = {
        "metric": ("metric", metrics, {"long_name": "metric"}),
        "factor": ("factor", names, {"long_name": "factor"}),
        "metric_unit": ("metric", units),
        "factor_unit": ("factor", factor_units),
    }
    failed = failed_samples(ds)
    attrs = {**attrs, "failed_samples": json.dumps([int(i) for i in failed])}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def _stack(rows: list, key: str, shape: tuple[int, ...]) -> np.ndarray:
    """``rows[i][key]`` stacked over the metrics, NaN for a metric without results."""
    return np.stack([np.full(shape, np.nan) if r is None else r[key] for r in rows])


def _rng(study: Any) -> np.random.Generator:
    """Bootstrap generator from the study seed (a Generator: SALib ignores a seed of 0)."""
    return np.random.default_rng(study.seed)


def sobol(
    ds: xr.Dataset, study: Any, conf_level: float = CONF_LEVEL, num_resamples: int = NUM_RESAMPLES
) -> xr.Dataset:
    """Sobol' first-order and total indices of the sensitivity metrics (SALib ``sobol``).

    Parameters
    ----------
    ds : xarray.Dataset
        The study's results, ``sample`` dimension in the Saltelli order of ``study.design()``.
    study : StudyDef
        A ``kind = "sensitivity"``, ``method = "sobol"`` study.
    conf_level : float
        Level of the bootstrap confidence intervals, in (0, 1).
    num_resamples : int
        Bootstrap resamples.

    Returns
    -------
    xarray.Dataset
        ``S1``, ``S1_conf``, ``ST``, ``ST_conf`` (metric x factor, dimensionless), with
        second order ``S2``, ``S2_conf`` (metric x factor x factor_b) when the design has
        it, ``blocks_used`` and ``note`` per metric; attributes ``method``, ``conf_level``,
        ``blocks_total``, ``calc_second_order``, ``failed_samples`` (JSON list).

    Raises
    ------
    AnalysisError
        No Saltelli design, a sample count that is not whole blocks, or fewer than
        :data:`MIN_BLOCKS` complete blocks of a metric.
    """
    from SALib.analyze import sobol as salib_sobol

    design, problem = _problem(study)
    names, d = list(problem["names"]), int(problem["num_vars"])
    second = _option(study, design, ("calc_second_order", "second_order"))
    if second is None:
        raise AnalysisError(f"study '{study.name}': the design does not say calc_second_order")
    size = 2 * d + 2 if second else d + 2
    _block_size(ds.sizes["sample"], size, "Saltelli blocks")
    metrics = sensitivity_metrics(ds, study)
    keys = ("S1", "S1_conf", "ST", "ST_conf", *(("S2", "S2_conf") if second else ()))

    def compute(y: np.ndarray, keep: np.ndarray):
        if np.ptp(y) <= 1e-12 * max(1.0, float(np.max(np.abs(y)))):
            return None, f"constant ({y[0]:.6g}) over the design: no variance to apportion"
        res = salib_sobol.analyze(
            problem,
            y,
            calc_second_order=bool(second),
            num_resamples=num_resamples,
            conf_level=conf_level,
            seed=_rng(study),
        )
        return {k: np.asarray(res[k], dtype=float) for k in keys}, ""

    used, notes, rows = _each_metric(ds, metrics, size, compute)
    out = {k: _stack(rows, k, (d, d) if k.startswith("S2") else (d,)) for k in keys}
    data = {
        k: (("metric", "factor", "factor_b") if k.startswith("S2") else ("metric", "factor"), v)
        for k, v in out.items()
    }
    data |= {"blocks_used": ("metric", used), "note": ("metric", np.array(notes, dtype=str))}
    attrs = {
        "method": "sobol",
        "conf_level": conf_level,
        "num_resamples": num_resamples,
        "blocks_total": ds.sizes["sample"] // size,
        "block_size": size,
        "calc_second_order": int(bool(second)),
    }
    res = _result(names, metrics, ds, data, attrs)
    return res.assign_coords(factor_b=("factor_b", names)) if second else res


def _morris_inputs(ds: xr.Dataset, names: list[str], size: int) -> np.ndarray:
    """The factor matrix (samples x factors) in the SALib problem's order, checked to be
    Morris trajectories: each step changes exactly one factor."""
    missing = [n for n in names if n not in ds]
    if missing:
        raise AnalysisError(f"factor variables {missing} are not in the dataset")
    x = np.column_stack([np.asarray(ds[n].values, dtype=float).ravel() for n in names])
    ran = np.asarray(ds["status"].values).ravel() == 0
    if not np.isfinite(x[ran]).all():
        j = int(np.flatnonzero(~np.isfinite(x[ran]).all(axis=0))[0])
        raise AnalysisError(
            f"factor '{names[j]}' is not finite in samples that ran: Morris needs finite "
            "factor values (a normal or lognormal factor maps Morris' end levels to +-inf)"
        )
    trajectories = x.reshape(-1, size, len(names))
    whole = np.isfinite(trajectories).all(axis=(1, 2))  # others hold failed samples only
    changed = np.count_nonzero(np.diff(trajectories, axis=1), axis=2)
    changed[~whole] = 1
    if np.any(changed != 1):
        t, s = np.argwhere(changed != 1)[0]
        raise AnalysisError(
            f"trajectory {t}, step {s}: {changed[t, s]} factors change at once; Morris needs "
            "one factor per step (the factor values do not follow the Morris design)"
        )
    return x


def _levels(study: Any, design: Any, x: np.ndarray, problem: dict) -> int:
    """Morris grid levels: the design's setting, checked against the steps of ``x``."""
    levels = _option(study, design, ("num_levels", "levels"))
    if levels is None:
        raise AnalysisError(f"study '{study.name}': the design does not say the Morris levels")
    bounds = np.asarray(problem["bounds"], dtype=float)
    size = len(bounds) + 1
    steps = np.abs(np.diff(x.reshape(-1, size, len(bounds)), axis=1)) / np.ptp(bounds, axis=1)
    steps = steps[np.isfinite(steps).all(axis=(1, 2))]
    uniform = np.array([d == "unif" for d in problem.get("dists", ["unif"] * len(bounds))])
    steps = steps[..., uniform]  # other distributions step by delta in probability only
    observed = np.unique(np.round(steps[steps > 0], 9))
    delta = levels / (2.0 * (levels - 1))
    if not np.allclose(observed, delta, rtol=1e-6):
        raise AnalysisError(
            f"Morris levels = {levels} means steps of {delta:.6g} of each factor's range; "
            f"the dataset's steps are {observed[:5].tolist()}"
        )
    return int(levels)


def morris(
    ds: xr.Dataset, study: Any, conf_level: float = CONF_LEVEL, num_resamples: int = NUM_RESAMPLES
) -> xr.Dataset:
    """Morris screening of the sensitivity metrics (SALib ``morris``).

    Parameters
    ----------
    ds : xarray.Dataset
        The study's results, ``sample`` dimension in trajectory order; the factor
        variables are the X matrix.
    study : StudyDef
        A ``kind = "sensitivity"``, ``method = "morris"`` study.
    conf_level, num_resamples
        Bootstrap confidence level of ``mu_star`` and its resamples.

    Returns
    -------
    xarray.Dataset
        ``mu_star``, ``mu_star_conf``, ``sigma``, ``mu`` (metric x factor; the metric's
        unit: the elementary effect over a factor's whole range), ``blocks_used``, ``note``
        per metric; attributes ``method``, ``num_levels``, ``blocks_total``,
        ``failed_samples``.

    Raises
    ------
    AnalysisError
        No Morris design, steps that change several factors, levels that do not match the
        steps, or fewer than :data:`MIN_BLOCKS` complete trajectories.
    """
    from SALib.analyze import morris as salib_morris

    design, problem = _problem(study)
    names, d = list(problem["names"]), int(problem["num_vars"])
    size = d + 1
    _block_size(ds.sizes["sample"], size, "Morris trajectories")
    x = _morris_inputs(ds, names, size)
    levels = _levels(study, design, x, problem)
    metrics = sensitivity_metrics(ds, study)
    keys = ("mu_star", "mu_star_conf", "sigma", "mu")

    def compute(y: np.ndarray, keep: np.ndarray):
        res = salib_morris.analyze(
            problem,
            x[np.repeat(keep, size)],
            y,
            num_resamples=num_resamples,
            conf_level=conf_level,
            num_levels=levels,
            seed=_rng(study),
        )
        return {k: np.asarray(res[k], dtype=float) for k in keys}, ""

    used, notes, rows = _each_metric(ds, metrics, size, compute)
    data = {k: (("metric", "factor"), _stack(rows, k, (d,))) for k in keys}
    data |= {"blocks_used": ("metric", used), "note": ("metric", np.array(notes, dtype=str))}
    attrs = {
        "method": "morris",
        "conf_level": conf_level,
        "num_resamples": num_resamples,
        "num_levels": levels,
        "blocks_total": ds.sizes["sample"] // size,
        "block_size": size,
    }
    return _result(names, metrics, ds, data, attrs)


def analyse(ds: xr.Dataset, study: Any) -> xr.Dataset | None:
    """The sensitivity analysis the study asks for (Sobol' or Morris), None for other kinds."""
    if study.kind != "sensitivity":
        return None
    method = (study.design().method or "").lower()
    if "morris" in method:
        return morris(ds, study)
    if "sobol" in method or "saltelli" in method:
        return sobol(ds, study)
    raise AnalysisError(f"study '{study.name}': unknown sensitivity method '{method}'")


def ranked(result: xr.Dataset, metric: str) -> list[dict[str, Any]]:
    """The factors of ``metric`` ranked by total index (Sobol') or mu* (Morris), largest
    first: one dict per factor with its indices (None where undefined)."""
    key = "ST" if result.attrs["method"] == "sobol" else "mu_star"
    names = [k for k in ("S1", "S1_conf", "ST", "ST_conf", "mu_star", "mu_star_conf", "sigma")]
    row = result.sel(metric=metric)
    order = np.argsort(-np.nan_to_num(row[key].values, nan=-np.inf), kind="stable")
    out = []
    for j in order:
        entry: dict[str, Any] = {"factor": str(result["factor"].values[j])}
        for k in names:
            if k in result:
                v = float(row[k].values[j])
                entry[k] = v if math.isfinite(v) else None
        out.append(entry)
    return out
