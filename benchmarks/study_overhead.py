"""CPU time per sample of a design study against the simulation it wraps, and the share of
the process running the client (issue 19's "< 10 %"; re-measured for issue 24).

    OPENBLAS_NUM_THREADS=1 python benchmarks/study_overhead.py [--samples 256] [--rounds 5]

Four ways of computing the same samples, interleaved round by round (the machine's load
drifts), CPU time (``time.process_time``: every thread of a process) per sample, medians:

1. bare: the base scene (step-50g, n = 3, ``radau``) as ``sarcomere run`` integrates it,
   start equilibrium + ``simulate``, in this process;
2. evaluator: an LHS study on that scene (load, pressure, k_s and C_tube +-10 %) through
   ``evaluate_batch`` in this process (factors applied, metrics; no Dask, no store);
3. and 4. the same study on the engine's embedded cluster of 1 and 2 workers
   (``run_chunks``, results written to a fresh Zarr store): the CPU of every worker
   process (read on the workers) plus that of this process, which runs the client, the
   scheduler and the store writes ("client"). One cluster at a time; the workers are warm
   (model built, library compiled) and the cluster's start is not counted. The client's
   CPU while idle (per second of wall time: Dask's periodic work) is printed too.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.simulation.simulate import simulate
from sarcomere.scenarios import binding
from sarcomere.scenarios.explore.engine import cluster_client, run_chunks
from sarcomere.scenarios.explore.evaluate import evaluate_batch
from sarcomere.scenarios.explore.spec import parse_study
from sarcomere.scenarios.explore.store import StudyStore
from sarcomere.scenarios.explore.study import Study

STUDY = """
[study]
kind = "sample"
base = "step-50g"
seed = 1
[study.sample]
method = "lhs"
count = {count}
[study.factors.load]
uniform = ["40 g", "60 g"]
[study.factors.pressure]
uniform = ["0.08 MPa", "0.12 MPa"]
[study.factors."aps.k_s"]
uniform = ["0.9", "1.1"]
relative = true
[study.factors."aps.C_tube"]
uniform = ["0.9", "1.1"]
relative = true
[solver]
method = "radau"
"""


def bare(study, runs: int = 20) -> float:
    """CPU seconds of one start equilibrium + simulate of the base scene."""
    sc = study.scene()
    b = binding.bind(sc)
    model = b.build("full")
    inputs, wanted, grid = binding.prepare(sc, b, model)
    settings = binding.solver_settings(sc, model)
    tic = time.process_time()
    for _ in range(runs):
        start = solve_equilibrium(model, {binding.P_CMD: 0.0}, b.overrides)
        simulate(
            model,
            sc.simulation.stop_time,
            inputs,
            b.overrides,
            x0=start.x,
            z0=start.z,
            settings=settings,
            t_out=grid,
            signals=wanted,
        )
    return (time.process_time() - tic) / runs


def evaluator(study, n: int) -> float:
    """CPU seconds per sample of ``evaluate_batch`` in this process."""
    tic = time.process_time()
    result = evaluate_batch(study, np.arange(n))
    assert not result.status.any(), result.error
    return (time.process_time() - tic) / n


def engine(study, client, tmp: Path, n: int) -> tuple[float, float]:
    """(all, client) CPU seconds per sample of the study on ``client``'s cluster."""
    layout = Study(study)._layout(study.design(), study.batch)
    store = StudyStore.open_or_create(tmp / f"{time.monotonic_ns()}.zarr", **layout)
    points = study.design().points  # as Study.run hands them to the tasks
    workers0, client0 = client.run(time.process_time), time.process_time()
    run_chunks(client, evaluate_batch, study, store, store.missing_chunks(), points=points)
    own = time.process_time() - client0
    workers = sum(client.run(time.process_time).values()) - sum(workers0.values())
    assert not (store.status() != 0).any(), "failed samples"
    return (own + workers) / n, own / n


def idle(client, seconds: float = 3.0) -> float:
    """CPU seconds per second of this process (client and scheduler) with nothing to do."""
    tic, wall = time.process_time(), time.perf_counter()
    time.sleep(seconds)
    return (time.process_time() - tic) / (time.perf_counter() - wall)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    study = parse_study(STUDY.format(count=args.samples), "overhead.toml")
    evaluate_batch(study, [0])  # warm: compile (or load) radau, probe k_s and C_tube
    rows: dict[str, list] = {"bare": [], "evaluator": [], "1 worker": [], "2 workers": []}
    load, idling = [os.getloadavg()[0]], []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            rows["bare"].append((bare(study), 0.0))
            rows["evaluator"].append((evaluator(study, args.samples), 0.0))
            for workers, name in ((1, "1 worker"), (2, "2 workers")):
                with cluster_client(workers) as client:  # one cluster at a time
                    client.run(evaluate_batch, study, np.array([0]))  # every worker warm
                    rows[name].append(engine(study, client, Path(tmp), args.samples))
                    idling.append(idle(client))
            load.append(os.getloadavg()[0])
    m = statistics.median
    ref, own = m(r[0] for r in rows["bare"]), m(r[0] for r in rows["evaluator"])
    print(f"load average (1 min) over the rounds: {min(load):.1f}-{max(load):.1f}")
    print(f"client process idle: {m(idling) * 1e3:.1f} ms CPU per second of wall time")
    for name, got in rows.items():
        cpu, client = m(r[0] for r in got), m(r[1] for r in got)
        spread = f"{min(r[0] for r in got) * 1e3:.2f}-{max(r[0] for r in got) * 1e3:.2f}"
        share = f", client {client * 1e3:.2f} ms" if client else ""
        print(
            f"{name}: {cpu * 1e3:.2f} ms CPU per sample ({spread}), {(cpu / ref - 1) * 100:+.1f} % "
            f"against bare, {(cpu / own - 1) * 100:+.1f} % against the evaluator{share}"
        )


if __name__ == "__main__":
    main()
