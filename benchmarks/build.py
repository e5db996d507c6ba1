"""Model build cost against chain length: ``hanging_load(n)`` (components, flattening)
and the first Functions a transient run asks of the model.

Each case is built once cold, then ``--repeats`` times; the median is reported [ms].
"first use": ``function("ode")``, ``function("signals")``, ``function("dae_jac")`` and
the linearisation of ``myofibril.length``, built on a fresh model (what a run adds to
the build). Timings on a shared machine are noisy: compare two versions by running this
script for each in turn, several times.

Usage::

    python benchmarks/build.py [--n 3 10 30] [--levels full grouped symmetric]
        [--repeats 7] [--out out/bench/build.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from sarcomere.dynamics.assemblies import hanging_load


def _first_use(model) -> None:
    for which in ("ode", "signals", "dae_jac"):
        model.function(which)
    model.linearization(["myofibril.length"])


def measure(n: int, level: str, repeats: int) -> dict:
    """Median build and first-use times [ms] of ``hanging_load(n, fidelity=level)``."""
    builds, uses = [], []
    for _ in range(repeats + 1):  # the first one cold, not counted
        tic = time.perf_counter()
        model = hanging_load(n, load_kg=0.05, fidelity=level)
        mid = time.perf_counter()
        _first_use(model)
        builds.append(1e3 * (mid - tic))
        uses.append(1e3 * (time.perf_counter() - mid))
    return {
        "n": n,
        "level": level,
        "build_ms": statistics.median(builds[1:]),
        "first_use_ms": statistics.median(uses[1:]),
        "states": model.nx,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[3, 10, 30])
    ap.add_argument("--levels", nargs="+", default=["full"])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    rows = []
    for level in args.levels:
        for n in args.n:
            row = measure(n, level, args.repeats)
            rows.append(row)
            print(
                f"{level:13s} n = {n:3d}: build {row['build_ms']:7.1f} ms, "
                f"first use {row['first_use_ms']:6.1f} ms ({row['states']} states)"
            )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
