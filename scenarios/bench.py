"""``sarcomere bench``: numerical studies of the simulation engine.

* ``sarcomere bench work-precision --out DIR [--quick]``: error against wall time for
  every integration method on three scenarios (:mod:`sarcomere.dynamics.studies.workprecision`);
  writes ``DIR/work_precision.json`` (records), one chart per scenario and
  ``DIR/summary.json``.
* ``sarcomere bench stability --out DIR [--quick]``: predicted against observed step
  limits of the explicit fixed-step methods (:mod:`sarcomere.dynamics.studies.stability`);
  writes ``DIR/stability.json``, two charts and ``DIR/summary.json``.
* ``sarcomere bench mpc --out DIR [--quick]``: time per step of the MPCs on the
  length-control scene, and the RTI NMPC's feedback latency and preparation, in Python and
  compiled (:mod:`sarcomere.scenarios.studies.mpc_speed`); writes ``DIR/mpc.json`` and
  ``DIR/summary.json``.

``--quick`` uses fewer tolerances, steps and repeats (under a minute each).
A metric a study cannot compute is None, printed with the study's note of why (do-mpc
not installed).
The CLI wires :func:`add_arguments` and :func:`handler` as the ``bench`` subcommand.
"""

from __future__ import annotations

import argparse
import importlib
import json
import time
from datetime import UTC, datetime
from pathlib import Path

from .catalog import version
from .outdir import check_out_dir, staged
from .progress import progress

STUDIES = {  # (module holding ``study``, solver line): imported only when run
    "work-precision": (
        "sarcomere.dynamics.studies.workprecision",
        "cvodes (reference: rtol 1e-12) against radau, rodas, rk4, radau_fixed, collocation, scipy",
    ),
    "stability": (
        "sarcomere.dynamics.studies.stability",
        "rk4 and euler; rodas held at fixed steps (reference: cvodes rtol 1e-10)",
    ),
    "mpc": (
        "sarcomere.scenarios.studies.mpc_speed",
        "plant cvodes rtol 1e-6; NMPC rti/ipopt/fatrop, LMPC daqp, plain Opti",
    ),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``STUDY --out DIR [--quick]``."""
    parser.add_argument("study", choices=sorted(STUDIES), help="which study to run")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--quick", action="store_true", help="fewer points and repeats (about a minute)"
    )


def handler(args: argparse.Namespace) -> int:
    """Run the study, write its files and ``summary.json``; print one line per file."""
    module, solver = STUDIES[args.study]
    run = importlib.import_module(module).study
    folder = check_out_dir(args.out, "--out")
    with staged(folder) as tmp:
        tic = time.perf_counter()
        with progress(f"bench {args.study}"):
            out = run(tmp, quick=args.quick)
        wall = time.perf_counter() - tic
        _write_summary(args, solver, out, wall, tmp)
    for p in ["summary.json", *(p.name for p in out["files"])]:
        print(folder / p)
    notes = out.get("notes", {})  # why a metric is None (an optional package missing)
    for key, value in out["metrics"].items():
        why = f" ({notes[key]})" if key in notes else ""
        print(f"  {key} = {value if value is None else f'{value:.4g}'}{why}")
    return 0


def _write_summary(args: argparse.Namespace, solver: str, out: dict, wall: float, tmp: Path):
    summary = {
        "scenario": f"bench {args.study}" + (" --quick" if args.quick else ""),
        "fidelity": "full",
        "solver": solver,
        "wall_time_s": wall,
        "metrics": out["metrics"],
        "provenance": {
            "sarcomere_version": version(),
            "utc": datetime.now(UTC).isoformat(timespec="seconds"),
        },
        "files": [p.name for p in out["files"]],
    }
    (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
