"""Model build cost against chain length: ``hanging_load(n)`` (components, flattening)
and the first Functions a transient run asks of the model.

Each case is built once cold, then ``--repeats`` times; the median is reported [ms].
"first use": ``function("ode")``, ``function("signals")``, ``function("dae_jac")`` and
the linearisation of ``myofibril.length``, built on a fresh model (what a run adds to
the build). Timings on a shared machine are noisy: compare two versions by running this
script for each in turn, several times.

``--radau``: the compiled ``radau`` library against n instead: the generated C (bytes,
lines), the time to generate it, to compile it (an empty cache folder each time) and, in
a new process, to load it from the cache (the model build excluded; the whole process
reported too).

Usage::

    python benchmarks/build.py [--n 3 10 30] [--levels full grouped symmetric]
        [--repeats 7] [--out out/bench/build.json]
    python benchmarks/build.py --radau [--n 3 10 30 100] [--out out/bench/radau_build.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as cs

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.simulation import compiled, radau
from sarcomere.dynamics.simulation.common import law_dae
from sarcomere.dynamics.simulation.settings import HELD


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


_LOAD = """
import sys, time
tic = time.perf_counter()
from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.simulation import radau
from sarcomere.dynamics.simulation.settings import HELD
model = hanging_load({n}, load_kg=0.05)
mid = time.perf_counter()
lib = radau.library(model, HELD)
assert not lib.compiled
print(time.perf_counter() - mid, time.perf_counter() - tic)
"""


def measure_radau(n: int) -> dict:
    """Generated C size and generate / compile / cached-load times [s] of ``radau`` at n."""
    model = hanging_load(n, load_kg=0.05)
    d = law_dae(model, HELD)
    rhs = cs.Function("sm_rhs", [d.t, d.x, d.w, d.p], [d.ode])
    row = {"n": n, "states": model.nx, "jac_nnz": cs.jacobian(d.ode, d.x).nnz()}
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["SARCOMERE_CACHE_DIR"] = tmp
        tic = time.perf_counter()
        sources = radau.generate_sources(rhs, Path(tmp))
        row["generate_s"] = time.perf_counter() - tic
        row["c_bytes"] = sum(p.stat().st_size for p in sources)
        row["c_lines"] = sum(len(p.read_text().splitlines()) for p in sources)
        units = [compiled.Unit(radau.SOURCE, radau.CFLAGS)]
        units += [compiled.Unit(p, radau.MODEL_CFLAGS) for p in sources]
        tic = time.perf_counter()
        compiled._compile(units, ("-lm",), Path(tmp))
        row["compile_s"] = time.perf_counter() - tic
        tic = time.perf_counter()
        lib = radau.library(model, HELD)  # generate + compile + load into the cache
        row["build_s"] = time.perf_counter() - tic
        assert lib.compiled
        code = _LOAD.format(n=n)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        if out.returncode:
            raise RuntimeError(out.stderr)
        row["cached_load_s"], row["cached_process_s"] = map(float, out.stdout.split())
    return row


def main_radau(ns: list[int], out: Path | None) -> None:
    rows = []
    print("   n  states  nnz(J)  C bytes  C lines  generate  compile  build  cached load (process)")
    for n in ns:
        r = measure_radau(n)
        rows.append(r)
        print(
            f"{n:4d} {r['states']:7d} {r['jac_nnz']:7d} {r['c_bytes']:8d} {r['c_lines']:8d} "
            f"{r['generate_s']:8.2f}s {r['compile_s']:7.2f}s {r['build_s']:6.2f}s "
            f"{r['cached_load_s']:8.3f}s ({r['cached_process_s']:.2f} s)"
        )
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(rows, indent=2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[3, 10, 30])
    ap.add_argument("--levels", nargs="+", default=["full"])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--radau", action="store_true", help="the compiled radau library")
    args = ap.parse_args()
    if args.radau:
        main_radau(args.n, args.out)
        return
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
