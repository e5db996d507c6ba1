"""Per-sample overhead of the design-study machinery against the simulation it wraps
(issue 19: < 10 % of the n = 3 step-50g simulation with ``radau``).

    OPENBLAS_NUM_THREADS=1 python benchmarks/study_overhead.py [--samples 64] [--repeats 5]

Reference: the step-50g scene with ``radau`` as ``sarcomere run`` integrates it (start
equilibrium + ``simulate`` with the scene's signals). Study: an LHS study on that scene
(load, pressure, k_s and C_tube +-10 %) evaluated by ``evaluate_batch`` in one process
(warm: compiled library, probes and model built); overhead = batch wall time minus the
time inside ``solve_equilibrium`` + ``simulate``, per sample. Medians over repeats.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.simulation.simulate import simulate
from sarcomere.scenarios import binding
from sarcomere.scenarios.explore.evaluate import evaluate_batch
from sarcomere.scenarios.explore.spec import parse_study

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


def scene_run_s(study) -> float:
    """One start equilibrium + simulate of the base scene as the scene runner does it."""
    sc = study.scene()
    b = binding.bind(sc)
    model = b.build("full")
    inputs, wanted, grid = binding.prepare(sc, b, model)
    settings = binding.solver_settings(sc, model)
    tic = time.perf_counter()
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
    return time.perf_counter() - tic


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    study = parse_study(STUDY.format(count=args.samples), "overhead.toml")
    evaluate_batch(study, [0])  # warm: compile (or load) radau, probe k_s and C_tube
    scene_run_s(study)
    ref, over, per, solve = [], [], [], []
    for _ in range(args.repeats):
        ref.append(statistics.median(scene_run_s(study) for _ in range(10)))
        r = evaluate_batch(study, np.arange(args.samples))
        assert not r.status.any(), r.error
        per.append(r.timing["total_s"] / args.samples)
        solve.append(r.timing["solve_s"] / args.samples)
        over.append((r.timing["total_s"] - r.timing["solve_s"]) / args.samples)
    m = statistics.median
    o, sim = m(over), m(solve)
    print(f"scene run (equilibrium + simulate, radau, n = 3): {m(ref) * 1e3:.2f} ms")
    print(f"study sample: {m(per) * 1e3:.2f} ms, equilibrium + simulate {sim * 1e3:.2f} ms")
    print(f"overhead per sample: {o * 1e3:.3f} ms = {o / m(ref) * 100:.1f} % of the scene run")
    print(f"  = {o / sim * 100:.1f} % of the sample's own equilibrium + simulate")


if __name__ == "__main__":
    main()
