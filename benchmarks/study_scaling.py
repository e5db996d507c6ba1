"""Design studies at scale (BENCHMARKS.md, "Design studies"): throughput against workers,
study overhead per sample, scheduler overhead per task, memory over a long study.

    OPENBLAS_NUM_THREADS=1 nice python benchmarks/study_scaling.py [--samples 384]
        [--batch 32] [--tasks 500] [--long 10000] [--workers 1 2]

1. Throughput: the n = 3 step-50g scene with ``radau`` over ``--samples`` loads (30-70 g),
   on an embedded LocalCluster of 1 and 2 workers, after a warm-up sample on every worker
   (model built, code compiled): samples/s and the parallel efficiency.
2. Study overhead per sample: the 1-worker run's wall time against the time spent
   integrating (equilibrium + simulate, timed inside each sample).
3. Scheduler overhead per task: ``--tasks`` tasks that compute nothing (1 sample each) on
   2 workers, results written to the store: wall time per task, and the batch size that
   keeps it under 5 % of a sample.
4. Memory per worker over a ``--long``-sample study of a cheap scene (n = 1, 50 ms, cvodes):
   the workers' resident set size every 10 % of the samples.
5. Projected samples/hour at 64 workers, with the assumptions printed.
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sarcomere.scenarios.explore.engine import cluster_client, run_chunks
from sarcomere.scenarios.explore.evaluate import evaluate_batch
from sarcomere.scenarios.explore.spec import parse_study
from sarcomere.scenarios.explore.store import StudyStore, check_out_folder
from sarcomere.scenarios.explore.study import Study

STEP = """
[study]
kind = "grid"
base = "step-50g"
batch = {batch}
[study.grid]
load = {{from = "30 g", to = "70 g", num = {samples}}}
[study.metrics]
names = ["stroke", "rise_time", "peak_tension"]
[solver]
method = "radau"
"""

CHEAP = """
[study]
kind = "grid"
base = "step-50g"
batch = {batch}
max_samples = {samples}
[study.grid]
load = {{from = "30 g", to = "70 g", num = {samples}}}
[study.metrics]
names = ["stroke", "peak_tension"]
[model]
n = 1
[simulation]
stop_time = "50 ms"
output_interval = "5 ms"
[inputs.pressure]
time = "10 ms"
"""


@dataclass
class Nothing:
    """A batch result with nothing computed (for the scheduler's own cost)."""

    indices: np.ndarray
    metrics: dict
    series: dict
    series_time: None
    status: np.ndarray
    error: list


def nothing(study, indices, points=None) -> Nothing:
    """Evaluate nothing: NaN metrics, status 0."""
    k = len(indices)
    metrics = {m.name: np.full(k, np.nan) for m in study.metrics}
    return Nothing(np.asarray(indices), metrics, {}, None, np.zeros(k, np.int8), [""] * k)


def _store(study, out: Path) -> StudyStore:
    """A fresh store for ``study`` in ``out``."""
    layout = Study(study)._layout(study.design(), study.batch)
    return StudyStore.open_or_create(check_out_folder(out), **layout)


def _current_rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def timed_run(study, tmp: Path, workers: int, evaluate=evaluate_batch, on_result=None):
    """(wall s, results) of a whole study on a fresh cluster after a warm-up sample on
    each worker."""
    store = _store(study, tmp / f"w{workers}-{time.monotonic_ns()}")
    points = study.design().points  # as Study.run hands them to the tasks
    results = []

    def keep(result) -> None:
        results.append(result)
        if on_result is not None:
            on_result(result)

    with cluster_client(workers) as client:
        client.run(evaluate, study, np.array([0]))  # every worker: model built, compiled
        tic = time.perf_counter()
        chunks = store.missing_chunks()
        run_chunks(client, evaluate, study, store, chunks, on_result=keep, points=points)
        wall = time.perf_counter() - tic
    return wall, results


def throughput(args, tmp: Path) -> dict:
    """Median wall time, samples/s and integration time per worker count, the counts
    interleaved over ``--repeats`` (the machine's load drifts)."""
    study = parse_study(STEP.format(samples=args.samples, batch=args.batch), "bench.toml")
    runs: dict[int, list] = {w: [] for w in args.workers}
    for _ in range(args.repeats):
        for w in args.workers:
            wall, results = timed_run(study, tmp, w)
            solve = sum(r.timing.get("solve_s", math.nan) for r in results)
            inside = sum(r.timing.get("total_s", math.nan) for r in results)
            assert not any(np.count_nonzero(r.status) for r in results), "failed samples"
            runs[w].append((wall, solve, inside))
    rows = {}
    n = args.samples
    for w, got in runs.items():
        wall, solve, inside = (statistics.median(x) for x in zip(*got, strict=True))
        rows[w] = dict(wall=wall, rate=n / wall, solve=solve, inside=inside)
        print(
            f"workers {w}: {n} samples in {wall:.2f} s = {n / wall:.2f} samples/s (median of "
            f"{len(got)}: " + ", ".join(f"{g[0]:.2f}" for g in got) + " s); integrating "
            f"{solve / n * 1e3:.1f} ms/sample, evaluate_batch {inside / n * 1e3:.1f} ms/sample"
        )
    for w, r in rows.items():
        per = r["wall"] * w / n  # worker-seconds per sample
        sim = r["solve"] / n
        print(
            f"study overhead per sample ({w} worker{'s' if w > 1 else ''}): "
            f"{(per - sim) * 1e3:.2f} ms = {(per - sim) / sim * 100:.1f} % of the "
            f"{sim * 1e3:.1f} ms integration (inside evaluate_batch "
            f"{(r['inside'] - r['solve']) / n * 1e3:.2f} ms, engine + store "
            f"{(r['wall'] * w - r['inside']) / n * 1e3:.2f} ms)"
        )
    for w, got in runs.items():
        busy = statistics.median(inside / (w * wall) for wall, _, inside in got)
        print(f"workers {w}: busy inside evaluate_batch {busy * 100:.0f} % of the wall time")
    if 1 in rows and 2 in rows:
        eff = rows[2]["rate"] / (2 * rows[1]["rate"])
        print(f"parallel efficiency at 2 workers (samples/s): {eff * 100:.0f} %")
    return rows


def store_writes(tmp: Path, n: int = 300) -> float:
    """Seconds per chunk written to a store (3 metrics, 1 sample per chunk)."""
    study = parse_study(CHEAP.format(samples=n, batch=1), "writes.toml")
    store = _store(study, tmp / "writes")
    parts = [nothing(study, np.array([i])) for i in range(n)]
    tic = time.perf_counter()
    for i, part in enumerate(parts):
        store.write_many([(i, part)])
    one = (time.perf_counter() - tic) / n
    store = _store(study, tmp / "writes8")
    tic = time.perf_counter()
    for i in range(0, n, 8):
        store.write_many([(j, parts[j]) for j in range(i, min(i + 8, n))])
    many = (time.perf_counter() - tic) / n
    print(f"store: {one * 1e3:.2f} ms per chunk written alone, {many * 1e3:.2f} ms in eights")
    return one


def scheduler_overhead(args, tmp: Path) -> float:
    study = parse_study(CHEAP.format(samples=args.tasks, batch=1), "tasks.toml")
    per_task = []
    for _ in range(3):
        wall, _ = timed_run(study, tmp, 2, evaluate=nothing)
        per_task.append(wall / args.tasks)
    med = statistics.median(per_task)
    print(
        f"scheduler + store overhead: {med * 1e3:.2f} ms per task (2 workers, {args.tasks} "
        f"empty 1-sample tasks, median of 3: "
        + ", ".join(f"{p * 1e3:.2f}" for p in per_task)
        + " ms)"
    )
    return med


def memory(args, tmp: Path) -> None:
    study = parse_study(CHEAP.format(samples=args.long, batch=args.long_batch), "long.toml")
    store = _store(study, tmp / "long")
    seen = [0]
    marks = []
    every = args.long // 10

    with cluster_client(2) as client:
        client.run(evaluate_batch, study, np.array([0]))

        def sample_memory(result) -> None:
            before = seen[0]
            seen[0] += len(result.indices)
            if seen[0] // every > before // every:
                rss = client.run(_current_rss)
                marks.append((seen[0], sorted(v / 2**20 for v in rss.values())))

        tic = time.perf_counter()
        run_chunks(
            client,
            evaluate_batch,
            study,
            store,
            store.missing_chunks(),
            on_result=sample_memory,
            points=study.design().points,
        )
        wall = time.perf_counter() - tic
    status = store.status()
    print(
        f"long study: {args.long} samples in {wall:.1f} s ({args.long / wall:.0f} samples/s, "
        f"{int(np.count_nonzero(status != 0))} failed, batch {args.long_batch})"
    )
    for n, rss in marks:
        print(f"  after {n:>6} samples: worker RSS " + ", ".join(f"{r:.0f} MiB" for r in rss))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=384)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--tasks", type=int, default=500)
    ap.add_argument("--long", type=int, default=10_000)
    ap.add_argument("--long-batch", type=int, default=50)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--skip", nargs="*", default=[], choices=["throughput", "tasks", "memory"])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rows = {} if "throughput" in args.skip else throughput(args, tmp)
        task = math.nan if "tasks" in args.skip else scheduler_overhead(args, tmp)
        store_writes(tmp)
        if rows.get(1) and not math.isnan(task):
            sim = rows[1]["solve"] / args.samples
            batch = math.ceil(task / (0.05 * sim))
            print(f"batch keeping the per-task overhead under 5 % of the integration: >= {batch}")
            per_sample = rows[1]["wall"] / args.samples
            eff = rows[2]["rate"] / (2 * rows[1]["rate"]) if 2 in rows else 1.0
            workers_bound = 64 * eff / per_sample
            for b in (args.batch, 64):
                client_bound = b / task
                rate = min(workers_bound, client_bound)
                print(
                    f"projected at 64 workers, batch {b}: {rate * 3600:,.0f} samples/hour = min("
                    f"64 x {1 / per_sample:.1f} samples/s per worker x {eff * 100:.0f} % "
                    f"efficiency, {1 / task:.0f} tasks/s the client + scheduler handle x {b})"
                )
        if "memory" not in args.skip:
            memory(args, tmp)


if __name__ == "__main__":
    main()
