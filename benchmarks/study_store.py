"""CPU time of writing one finished task's chunk to a study's Zarr store
(``StudyStore.write_many``: every metric, the error texts, then the status), the
installed sarcomere against others side by side (BENCHMARKS.md, "Design studies").

    OPENBLAS_NUM_THREADS=1 python benchmarks/study_store.py [--chunks 200] [--rounds 5]
        [--python /other/venv/bin/python ...]

Each round runs one fresh process per interpreter (this one first, then each
``--python``, interleaved round by round) that makes a store of ``--chunks`` chunks of 32
samples (6 metrics; with ``--series``, 2 series of 101 points too) and writes every
chunk: CPU time of the process (``time.process_time``: all its threads, Zarr's event
loop included) and wall time per chunk. Medians over the rounds, and the median over the
rounds of each interpreter's CPU time divided by this one's in the same round.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

CHUNK, METRICS, SERIES_POINTS = 32, 6, 101


def measure(chunks: int, series: bool) -> dict:
    """Write ``chunks`` chunks to a fresh store; CPU and wall ms per chunk."""
    from sarcomere.scenarios.explore.store import Column, StudyStore

    n = chunks * CHUNK
    signals = ["series_a", "series_b"] if series else []
    with tempfile.TemporaryDirectory() as tmp:
        store = StudyStore.open_or_create(
            Path(tmp) / "study.zarr",
            definition={"bench": 1},
            fingerprint="0" * 64,
            factors=[(Column("load", "kg", "load"), np.linspace(0.0, 0.1, n))],
            metrics=[Column(f"m{i}", "1", f"m{i}") for i in range(METRICS)],
            series=[Column(s, "m", s) for s in signals],
            series_time=np.linspace(0.0, 1.0, SERIES_POINTS) if series else None,
            chunk=CHUNK,
            attrs={},
        )
        rng = np.random.default_rng(0)
        results = [
            SimpleNamespace(
                indices=np.arange(k * CHUNK, (k + 1) * CHUNK),
                metrics={f"m{i}": rng.random(CHUNK) for i in range(METRICS)},
                series={s[7:]: rng.random((CHUNK, SERIES_POINTS)) for s in signals},
                status=np.zeros(CHUNK, np.int8),
                error=[""] * CHUNK,
            )
            for k in range(chunks)
        ]
        store.write(0, results[0])  # warm: the event loop and the codecs
        cpu, wall = time.process_time(), time.perf_counter()
        for k in range(1, chunks):
            store.write(k * CHUNK, results[k])
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    return {"cpu_ms": cpu / (chunks - 1) * 1e3, "wall_ms": wall / (chunks - 1) * 1e3}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chunks", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--series", action="store_true")
    ap.add_argument("--python", nargs="*", default=[], help="other interpreters to compare")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(measure(args.chunks, args.series)))
        return
    pythons = [sys.executable, *args.python]
    runs: dict[str, list[dict]] = {p: [] for p in pythons}
    for _ in range(args.rounds):
        for python in pythons:
            cmd = [python, __file__, "--one", "--chunks", str(args.chunks)]
            done = subprocess.run(cmd + ["--series"] * args.series, capture_output=True)
            runs[python].append(json.loads(done.stdout.decode().splitlines()[-1]))
    m = statistics.median
    first = [r["cpu_ms"] for r in runs[sys.executable]]
    for python, rows in runs.items():
        cpu, wall = [r["cpu_ms"] for r in rows], [r["wall_ms"] for r in rows]
        ratio = m(c / f for c, f in zip(cpu, first, strict=True))  # paired by round
        print(
            f"{python}: CPU {m(cpu):.2f} ms per chunk ({min(cpu):.2f}-{max(cpu):.2f}), "
            f"{ratio:.2f}x this one's in the same rounds; "
            f"wall {m(wall):.2f} ms ({min(wall):.2f}-{max(wall):.2f})"
        )


if __name__ == "__main__":
    main()
