"""A fit's files: ``summary.json``, the fitted parameter file ``fitted.toml`` (the format
scenes, studies and FMU export read: docs/fitting.md) and the plots (:mod:`.plots`), all
of one run or none (:func:`..outdir.staged`)."""

from __future__ import annotations

import datetime
import json
import math
import subprocess
from pathlib import Path

from ..outdir import staged
from .data import sampling_note


def _commit() -> str:
    try:
        done = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=False,
            cwd=Path(__file__).parent,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return done.stdout.strip() or "unknown"


def _num(x: float | None):
    return None if x is None or not math.isfinite(x) else float(x)


def summary(result) -> dict:
    """The JSON-ready summary of a :class:`~.run.FitResult`."""
    b = result.built
    est = []
    for k, (e, value) in enumerate(zip(b.params, result.solution.theta, strict=True)):
        prof = result.profiles.get(k)
        est.append(
            {
                "name": e.name,
                "parameter": b.origin[k],
                "value": float(value),
                "unit": e.unit,
                "start": e.start,
                "bounds": [e.low, e.high],
                "scale": "log" if e.log else "linear",
                "sd_fisher": _num(result.fisher.sd[k]),
                "interval_fisher_95": [_num(x) for x in result.fisher.interval[k]],
                "interval_profile_95": [_num(prof.low), _num(prof.high)] if prof else None,
                "profile": {
                    "values": prof.values,
                    "rise": prof.rise,
                    "failed_solves": prof.failed,
                    "on_bounds_at_crossing": {
                        side: [b.params[j].name for j in held]
                        for side, held in zip(("lower", "upper"), prof.on_bounds, strict=True)
                    },
                }
                if prof
                else None,
                **result.verdicts[k],
            }
        )
    corr = [[_num(x) for x in row] for row in result.fisher.correlation]
    strip = ("data", "prediction", "sample")

    def lean(metrics: dict) -> dict:
        return {
            e: {s: {k: v for k, v in r.items() if k not in strip} for s, r in m.items()}
            for e, m in metrics.items()
        }

    starts = result.starts
    return {
        "fit": b.spec.name,
        "description": b.spec.description,
        "method": b.spec.method,
        "estimates": est,
        "correlation": {"names": [e.name for e in b.params], "matrix": corr},
        "singular_values": result.fisher.singular_values.tolist(),
        "cost_chi2": result.solution.cost,
        "residuals": int(len(result.solution.residuals)),
        "noise_sigma": result.sigma,
        "noise": {
            s: {"sigma": nz.sigma, "relative": nz.relative, "estimated": nz.sigma is None}
            for s, nz in b.problem.noise.items()
        },
        "sampling": sampling_note(
            {x.spec.name: x.table for x in b.experiments if x.spec.kind == "time-series"}
        ),
        "fitted": lean(result.metrics),
        "validation": lean(result.validation),
        "starts": {
            "total": len(starts),
            "reached_best": result.converged_starts,
            "within_chi2_1_of_best": result.equivalent_starts,
            "dropped": sum(s.dropped for s in starts),
            "dropped_why": sorted({s.status for s in starts if s.dropped}),
        },
        "design": result.design,
        "solver": {"status": result.solution.status, "iterations": result.solution.iterations},
        "integration": result.grid,
        "wall_time_s": result.wall_time,
    }


def _quantity(value: float, unit: str) -> str:
    return f"{value:.10g}" if unit in ("1", "") else f"{value:.10g} {unit}"


def fitted_toml(result, created: datetime.datetime | None = None) -> str:
    """The fitted parameter file: shared parameters under ``[parameters]`` with their
    ``[sources]``; per-experiment values as comments (they belong to one experiment)."""
    b = result.built
    when = (created or datetime.datetime.now(datetime.UTC)).strftime("%Y-%m-%dT%H:%M:%SZ")
    fitted_to = ", ".join(x.spec.name for x in b.experiments if not x.spec.validation)
    lines = [
        f"# Written by sarcomere fit '{b.spec.name}' ({when}, commit {_commit()})",
        "[fitted]",
        f"fit = {json.dumps(b.spec.name)}",
        f'created_utc = "{when}"',
        "",
        "[parameters]",
    ]
    sources, comments = [], []
    for k, (e, value) in enumerate(zip(b.params, result.solution.theta, strict=True)):
        prof = result.profiles.get(k)
        if "@" in e.name:
            comments.append(f"# {json.dumps(e.name)} = {json.dumps(_quantity(value, e.unit))}")
            continue
        lines.append(f"{json.dumps(e.name)} = {json.dumps(_quantity(value, e.unit))}")
        if prof is not None and prof.crosses:
            interval = f"95 % profile interval [{prof.low:.6g}, {prof.high:.6g}] {e.unit}"
        else:
            lo, hi = result.fisher.interval[k]
            interval = f"95 % Fisher interval [{lo:.6g}, {hi:.6g}] {e.unit}"
        verdict = result.verdicts[k]["verdict"]
        src = f"fitted by sarcomere fit '{b.spec.name}' to {fitted_to}; {interval}; {verdict}"
        sources.append(f"{json.dumps(e.name)} = {json.dumps(src)}")
    if comments:
        lines += ["", "# per-experiment values (not shared; for the record):", *comments]
    lines += ["", "[sources]", *sources]
    return "\n".join(lines) + "\n"


def write(result, out: Path, plots: bool = True) -> list[str]:
    """Write every file of ``result`` into ``out`` (replaced only on success)."""
    with staged(out) as tmp:
        (tmp / "summary.json").write_text(json.dumps(summary(result), indent=2) + "\n")
        (tmp / "fitted.toml").write_text(fitted_toml(result))
        if plots:
            from .plots import draw

            draw(result, tmp)
        names = sorted(p.name for p in tmp.iterdir())
    return names
