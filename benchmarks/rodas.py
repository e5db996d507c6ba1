"""The compiled Rosenbrock method ``rodas`` (Rodas4) against the compiled Radau IIA
``radau`` at equal accuracy, on the three work-precision scenes, in CPU time.

Scenes: :func:`sarcomere.dynamics.studies.workprecision.scenarios` (n = 3 by default:
ramp, step, vent; 2 s, 201 saved points). Accuracy: the l2 error of that module against
CVODES at rtol 1e-12. Each method is swept over rtol = 10^-3 ... 10^-9 in half decades
(atol = rtol 1e-3). Timing: every round calls every (scene, method, rtol) once in turn
(interleaved, so machine load hits both methods alike), ``--rounds`` rounds after a
warm-up, process CPU time (``time.process_time``) per call, medians; the CPU time at
each target error is interpolated log-log between the two sweep points that bracket it
(:func:`~sarcomere.dynamics.studies.workprecision.wall_at_error`).

Usage::

    python benchmarks/rodas.py --out out/bench/rodas.json [--rounds 7] [--n 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from sarcomere.dynamics.errors import SarcomereError
from sarcomere.dynamics.simulation.simulate import SolverSettings
from sarcomere.dynamics.studies import workprecision as wp

METHODS = ("rodas", "radau")
TOLERANCES = tuple(10.0 ** (-k / 2) for k in range(6, 19))
TARGETS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--n", type=int, default=3)
    args = ap.parse_args()
    scenes = wp.scenarios(args.n)
    points = []  # (scene, method, rtol, settings)
    records = {}
    for name, sc in scenes.items():
        ref = wp.reference(sc, check_rtol=1e-8)
        model, _ = sc.setup()
        for m in METHODS:
            for tol in TOLERANCES:
                s = SolverSettings(m, tol, tol * wp.ATOL_PER_RTOL)
                try:
                    res = sc.run(s)  # warm-up (compiles once per model and law)
                except SarcomereError as exc:  # a failing point is recorded
                    records[(name, m, tol)] = {"status": "failed", "message": str(exc)[:200]}
                    continue
                final, l2 = wp.state_errors(wp.states(res, model), ref)
                records[(name, m, tol)] = {
                    "scenario": name,
                    "method": m,
                    "rtol": tol,
                    "step_s": None,
                    "status": "ok",
                    "error_l2": l2,
                    "error_final": final,
                    "n_steps": res.meta["n_steps"],
                    "n_rejected": res.meta["n_rejected"],
                    "n_rhs": res.meta["n_rhs"],
                    "n_jac": res.meta["n_jac"],
                    "n_lu": res.meta["n_lu"],
                    "cpu": [],
                }
                points.append((name, m, tol, s))
    for _ in range(args.rounds):
        for name, m, tol, s in points:
            tic = time.process_time()
            scenes[name].run(s)
            records[(name, m, tol)]["cpu"].append(time.process_time() - tic)
    for r in records.values():
        if r["status"] == "ok":
            r["wall_time_s"] = statistics.median(r.pop("cpu"))  # CPU median (the key wp reads)
    summary = {}
    for name in scenes:
        recs = [r for r in records.values() if r.get("scenario") == name]
        for target in TARGETS:
            cpu = {m: wp.wall_at_error(recs, m, target) for m in METHODS}
            ratio = cpu["rodas"] / cpu["radau"] if cpu["rodas"] and cpu["radau"] else None
            summary[f"{name} {target:g}"] = {**cpu, "rodas_over_radau": ratio}
            fmt = {k: "-" if v is None else f"{v * 1e3:.3g} ms" for k, v in cpu.items()}
            r = "-" if ratio is None else f"{ratio:.2f}"
            print(f"{name:5s} error {target:g}: rodas {fmt['rodas']}, radau {fmt['radau']}, {r}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows = list(records.values())
    args.out.write_text(json.dumps({"records": rows, "cpu_at_error_s": summary}, indent=1))
    for r in sorted(rows, key=lambda r: (r.get("scenario", ""), r.get("method", ""))):
        if r["status"] == "ok":
            print(
                f"  {r['scenario']:5s} {r['method']:5s} rtol {r['rtol']:.1e}: l2 "
                f"{r['error_l2']:.2e}, {r['n_steps']} steps ({r['n_rejected']} rejected), "
                f"{r['n_rhs']} rhs, {r['n_lu']} LU, CPU {r['wall_time_s'] * 1e3:.3f} ms"
            )


if __name__ == "__main__":
    main()
