"""Scene x fidelity level: error against "full" and end-to-end wall time, and what
``fidelity = "auto"`` picks, all in one process.

Scenes: the packaged transients (step-50g, step-50g-auto, ramp-50g, sine-sweep-50g,
vent-0g) and study variants of them (a small sweep, the ramp and the step at n = 10 and 30,
a 10 s ramp). Levels: the flattened ones (:data:`~sarcomere.dynamics.assemblies.FIDELITIES`)
run as ``[model] fidelity``; ``linear`` and ``equilibrium_path`` on the full model
(:mod:`sarcomere.dynamics.fidelity`). Error: ``max |L - L_full| / span(L_full)`` of
``myofibril.length`` against the full level at the scene's own solver settings. Time: the
median of ``--repeats`` warm calls of the transient runner (model build, start
equilibrium, simulation; no file writing), the same for every level; for linear and
equilibrium_path, build + equilibrium path + the level. "auto" is the runner with
``fidelity = "auto"``: its prediction and the chosen level's run.

Usage::

    python benchmarks/fidelity.py --out out/bench/fidelity.json [--repeats 3] [--quick]
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import time
from pathlib import Path

import numpy as np

from sarcomere.dynamics import fidelity as ladder
from sarcomere.dynamics.assemblies import FIDELITIES
from sarcomere.dynamics.errors import SarcomereError
from sarcomere.scenarios import dynamic, parse_scenario
from sarcomere.scenarios.loader import packaged_scenarios

LEVELS = (*FIDELITIES, "linear", "equilibrium_path", "auto")
SIGNAL = "myofibril.length"


def _packaged(name: str) -> str:
    return packaged_scenarios()[name].read_text()


def scenes(quick: bool) -> dict[str, str]:
    """Scene name -> TOML text (fidelity set per level later)."""
    out = {n: _packaged(n) for n in ("step-50g", "step-50g-auto", "ramp-50g", "sine-sweep-50g")}
    out["vent-0g"] = _packaged("vent-0g")
    out["small-sweep-50g (3 kPa)"] = out["sine-sweep-50g"].replace(
        'amplitude = "0.03 MPa"', 'amplitude = "3 kPa"'
    )
    out["ramp-50g 10 s"] = (
        out["ramp-50g"]
        .replace('duration = "2 s"', 'duration = "10 s"')
        .replace('stop_time = "2.5 s"', 'stop_time = "10.5 s"')
    )
    for n in (10,) if quick else (10, 30):
        for base in ("step-50g", "ramp-50g"):
            out[f"{base} n={n}"] = re.sub(r"(?m)^n = 3$", f"n = {n}", out[base])
    return out


def _with_level(text: str, level: str) -> str:
    text = re.sub(r'(?m)^fidelity = "\w+"', f'fidelity = "{level}"', text)
    if level != "auto":
        text = re.sub(r"(?m)^tolerance = .*\n", "", text)
    return text


def _timed(fn, repeats: int):
    fn()  # cold: CasADi Functions built
    walls, out = [], None
    for _ in range(repeats):
        tic = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - tic)
    return out, statistics.median(walls)


def _ladder_level(text: str, level: str):
    """Run linear or equilibrium_path the way ``auto`` does: build full, path, level."""
    sc = parse_scenario(_with_level(text, "full"), "scene.toml")
    b = dynamic.bind(sc)
    full = b.build("full")
    inputs, wanted, grid = dynamic._prepare(sc, b, full)
    name = next(iter(inputs))
    path = ladder.equilibrium_path(full, name, inputs[name](grid), b.overrides)
    run = ladder.run_linear if level == "linear" else ladder.run_equilibrium_path
    return run(full, path, inputs, grid, [SIGNAL])


def study(repeats: int, quick: bool) -> dict:
    rows = {}
    for scene, text in scenes(quick).items():
        ref = None
        row = {}
        for level in LEVELS:
            try:
                if level in ("linear", "equilibrium_path"):
                    res, wall = _timed(lambda t=text, lv=level: _ladder_level(t, lv), repeats)
                    extra = {}
                else:
                    sc = parse_scenario(_with_level(text, level), "scene.toml")
                    out, wall = _timed(lambda sc=sc: dynamic.run_transient(sc, Path(".")), repeats)
                    res = out.results["main"]
                    extra = {}
                    if level == "auto":
                        rep = out.extra["fidelity_auto"]
                        extra = {
                            "chosen": rep["chosen"],
                            "predicted_error": rep["predicted_error"][rep["chosen"]],
                            "predicted": rep["predicted_error"],
                        }
            except SarcomereError as exc:
                row[level] = {"failed": " ".join(str(exc).split())[:200]}
                continue
            if level == "full":
                ref = res[SIGNAL]
            err = float(np.max(np.abs(res[SIGNAL] - ref)) / np.ptp(ref))
            row[level] = {"error": err, "wall_time_s": wall, **extra}
            print(f"{scene:28s} {level:17s} error {err:9.2e} time {wall * 1e3:8.1f} ms {extra}")
        for rec in row.values():
            if "wall_time_s" in rec:
                rec["speedup_vs_full"] = row["full"]["wall_time_s"] / rec["wall_time_s"]
        rows[scene] = row
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/fidelity.json"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="n = 10 only, no n = 30")
    args = parser.parse_args()
    rows = study(args.repeats, args.quick)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
