"""Scene x fidelity level: error against "full" and end-to-end time, and what
``fidelity = "auto"`` picks, all in one process.

Scenes: the packaged transients (step-50g, step-50g-auto, ramp-50g, sine-sweep-50g,
vent-0g, and the auto scenes dither-50g-auto, step-50g-n30-auto, ramp-50g-n60-auto,
cycle-50g-n60-auto) and study variants (a 3 kPa sweep, a 10 s ramp, the step and the
ramp at n = 10). Levels: the flattened ones (:data:`~sarcomere.dynamics.assemblies.
FIDELITIES`), ``linear`` and ``equilibrium_path`` (on the full model,
:mod:`sarcomere.dynamics.fidelity`), each run as ``[model] fidelity``; on chains of 30
and more only full, grouped, symmetric and auto (the others cost many full runs there:
quasi_static 7-11 s and the full model's equilibrium path 2-13 s at n = 30, static_chain
is refused above n = 20).

Error: ``max |y - y_full| / span(y_full)`` over the scene's ``[outputs] signals``
(default ``myofibril.length``), against full at the scene's own solver settings.
Time, "end to end" (wall, and this process's CPU time, which a loaded machine does not
inflate): the transient runner's own time for the scene (bind, build, start
equilibrium, prediction, solve, output signals and metrics; not Python start-up, file
writing or plots). Every level of a scene is timed once cold, then in ``--repeats``
rounds that run every level once each, so the shared machine's load falls on all of
them alike; the median is reported, and each level's ratio to full's median.
BLAS/LAPACK run with the threads the CLI uses (``SARCOMERE_BLAS_THREADS``, default 1;
scenarios/threads.py); ``--blas-threads default`` leaves the libraries' own pools.

Usage::

    python benchmarks/fidelity.py --out out/bench/fidelity.json [--repeats 3] [--quick]
        [--only step-50g-n30-auto ...] [--levels auto ...]
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import re
import statistics
import time
from pathlib import Path

import numpy as np

from sarcomere.dynamics.assemblies import FIDELITIES
from sarcomere.dynamics.errors import SarcomereError
from sarcomere.scenarios import parse_scenario, transient
from sarcomere.scenarios.loader import packaged_scenarios
from sarcomere.scenarios.threads import limited_blas

LEVELS = (*FIDELITIES, "linear", "equilibrium_path", "auto")
LONG_CHAIN_LEVELS = ("full", "grouped", "symmetric", "auto")
PACKAGED = (
    "step-50g",
    "step-50g-auto",
    "ramp-50g",
    "sine-sweep-50g",
    "vent-0g",
    "dither-50g-auto",
    "step-50g-n30-auto",
    "ramp-50g-n60-auto",
    "cycle-50g-n60-auto",
)


def _packaged(name: str) -> str:
    return packaged_scenarios()[name].read_text()


def scenes(quick: bool) -> dict[str, str]:
    """Scene name -> TOML text (fidelity set per level later)."""
    names = PACKAGED[:6] if quick else PACKAGED
    out = {n: _packaged(n) for n in names}
    out["small-sweep-50g (3 kPa)"] = out["sine-sweep-50g"].replace(
        'amplitude = "0.03 MPa"', 'amplitude = "3 kPa"'
    )
    out["ramp-50g 10 s"] = (
        out["ramp-50g"]
        .replace('duration = "2 s"', 'duration = "10 s"')
        .replace('stop_time = "2.5 s"', 'stop_time = "10.5 s"')
    )
    for base in ("step-50g", "ramp-50g"):
        out[f"{base} n=10"] = re.sub(r"(?m)^n = 3$", "n = 10", out[base])
    return out


def _with_level(text: str, level: str) -> str:
    text = re.sub(r'(?m)^fidelity = "\w+"', f'fidelity = "{level}"', text)
    if level != "auto":
        text = re.sub(r"(?m)^tolerance = .*\n", "", text)
    return text


def _runner(text: str, level: str):
    """The transient runner on the scene at ``level``: (result, auto report or {})."""
    sc = parse_scenario(_with_level(text, level), "scene.toml")
    out = transient.run_transient(sc, Path("."))
    rep = out.extra.get("fidelity_auto", {})
    extra = {}
    if rep:
        extra = {
            "chosen": rep["chosen"],
            "predicted_error": rep["predicted_error"][rep["chosen"]],
            "predicted": rep["predicted_error"],
            "predicted_against": rep["predicted_against"],
        }
    return out.results["main"], extra


def _signals(text: str) -> list[str]:
    sc = parse_scenario(_with_level(text, "full"), "scene.toml")
    return list(sc.outputs.signals) or ["myofibril.length"]


def study(
    repeats: int, quick: bool, only: list[str] | None = None, keep: list[str] | None = None
) -> dict:
    rows = {}
    for scene, text in scenes(quick).items():
        if only and scene not in only:
            continue
        signals = _signals(text)
        long_chain = int(re.search(r"(?m)^n = (\d+)$", text).group(1)) >= 30
        levels = LONG_CHAIN_LEVELS if long_chain else LEVELS
        if keep:
            levels = tuple(lv for lv in levels if lv in keep or lv == "full")
        calls, row, walls, cpus = {}, {}, {}, {}
        for level in levels:
            calls[level] = lambda t=text, lv=level: _runner(t, lv)
        results = {}
        for level in levels:  # cold: CasADi Functions, imports
            try:
                results[level] = calls[level]()
                walls[level], cpus[level] = [], []
            except SarcomereError as exc:
                row[level] = {"failed": " ".join(str(exc).split())[:200]}
        for _ in range(repeats):  # rounds of every level: side by side
            for level in walls:
                gc.collect()  # no level pays for the garbage of the one before
                tic, cpu = time.perf_counter(), time.process_time()
                results[level] = calls[level]()
                walls[level].append(time.perf_counter() - tic)
                cpus[level].append(time.process_time() - cpu)
        ref = results["full"][0]
        for level in walls:
            res, extra = results[level]
            err = max(float(np.max(np.abs(res[n] - ref[n])) / np.ptp(ref[n])) for n in signals)
            wall, cpu = statistics.median(walls[level]), statistics.median(cpus[level])
            row[level] = {"error": err, "wall_time_s": wall, "cpu_time_s": cpu, **extra}
            row[level]["speedup_vs_full"] = statistics.median(walls["full"]) / wall
            row[level]["cpu_speedup_vs_full"] = statistics.median(cpus["full"]) / cpu
            print(
                f"{scene:26s} {level:17s} error {err:9.2e} time {wall * 1e3:8.1f} ms "
                f"x{row[level]['speedup_vs_full']:5.2f} cpu {cpu * 1e3:8.1f} ms "
                f"x{row[level]['cpu_speedup_vs_full']:5.2f} {extra.get('chosen', '')}",
                flush=True,
            )
        rows[scene] = row
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/fidelity.json"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="no chains of 30 and more")
    parser.add_argument("--only", nargs="+", help="these scenes alone")
    parser.add_argument("--levels", nargs="+", help="these levels alone (and full)")
    parser.add_argument(
        "--blas-threads", choices=("cli", "default"), default="cli", help="BLAS thread pools"
    )
    args = parser.parse_args()
    with limited_blas() if args.blas_threads == "cli" else contextlib.nullcontext():
        rows = study(args.repeats, args.quick, args.only, args.levels)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
