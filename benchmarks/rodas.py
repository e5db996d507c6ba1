"""The compiled Rosenbrock method ``rodas`` (Rodas4) against the compiled Radau IIA
``radau`` at equal accuracy, on the three work-precision scenes, in CPU time.

Scenes: :func:`sarcomere.dynamics.studies.workprecision.scenarios` (n = 3 by default:
ramp, step, vent; 2 s, 201 saved points). Accuracy: the l2 error of that module against
CVODES at rtol 1e-12. Each method is swept over rtol = 10^-3 ... 10^-9 in half decades
(atol = rtol 1e-3). Timing: every round calls every (scene, method, rtol) once in turn
(interleaved, so machine load hits both methods alike), ``--rounds`` rounds after a
warm-up, process CPU time (``time.process_time``) per call, medians; the CPU time at
each target error is interpolated log-log between the two sweep points that bracket it
(:func:`~sarcomere.dynamics.studies.workprecision.wall_at_error`). Two times per call:
the whole ``simulate`` call, and the part inside the method's run function (the C
integrator and its thin ctypes wrapper, summed over the segments), which leaves out the
Python that every method pays alike (input and domain checks, outputs).

Usage::

    python benchmarks/rodas.py --out out/bench/rodas.json [--rounds 7] [--n 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from pathlib import Path

from sarcomere.dynamics.errors import SarcomereError
from sarcomere.dynamics.simulation.settings import METHODS
from sarcomere.dynamics.simulation.simulate import SolverSettings
from sarcomere.dynamics.studies import workprecision as wp

COMPARED = ("rodas", "radau")
TOLERANCES = tuple(10.0 ** (-k / 2) for k in range(6, 19))
TARGETS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


_INSIDE = [0.0]  # CPU seconds spent inside the methods' run functions


def _timed(run):
    def timed(seg):
        tic = time.process_time()
        try:
            return run(seg)
        finally:
            _INSIDE[0] += time.process_time() - tic

    return timed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--n", type=int, default=3)
    args = ap.parse_args()
    scenes = wp.scenarios(args.n)
    for m in COMPARED:
        METHODS[m] = dataclasses.replace(METHODS[m], run=_timed(METHODS[m].run))
    points = []  # (scene, method, rtol, settings)
    records = {}
    for name, sc in scenes.items():
        ref = wp.reference(sc, check_rtol=1e-8)
        model, _ = sc.setup()
        for m in COMPARED:
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
                    "inside": [],
                }
                points.append((name, m, tol, s))
    for _ in range(args.rounds):
        for name, m, tol, s in points:
            _INSIDE[0] = 0.0
            tic = time.process_time()
            scenes[name].run(s)
            records[(name, m, tol)]["cpu"].append(time.process_time() - tic)
            records[(name, m, tol)]["inside"].append(_INSIDE[0])
    for r in records.values():
        if r["status"] == "ok":
            r["cpu_s"] = statistics.median(r.pop("cpu"))
            r["method_cpu_s"] = statistics.median(r.pop("inside"))
    summary = {}
    for name in scenes:
        recs = [r for r in records.values() if r.get("scenario") == name]
        for target in TARGETS:
            line = {}
            for key in ("cpu_s", "method_cpu_s"):  # interpolated by wall_at_error's key
                for r in recs:
                    r["wall_time_s"] = r.get(key)
                cpu = {m: wp.wall_at_error(recs, m, target) for m in COMPARED}
                ratio = cpu["rodas"] / cpu["radau"] if cpu["rodas"] and cpu["radau"] else None
                line[key] = {**cpu, "rodas_over_radau": ratio}
            summary[f"{name} {target:g}"] = line
            text = []
            for key, v in line.items():
                f = {m: "-" if v[m] is None else f"{v[m] * 1e3:.3g}" for m in COMPARED}
                r = "-" if v["rodas_over_radau"] is None else f"{v['rodas_over_radau']:.2f}"
                text.append(f"{key} rodas {f['rodas']} ms, radau {f['radau']} ms, ratio {r}")
            print(f"{name:5s} error {target:g}: " + "; ".join(text))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows = list(records.values())
    for r in rows:
        r.pop("wall_time_s", None)  # the interpolation's key, not a wall time
    args.out.write_text(json.dumps({"records": rows, "cpu_at_error_s": summary}, indent=1))
    for r in sorted(rows, key=lambda r: (r.get("scenario", ""), r.get("method", ""))):
        if r["status"] == "ok":
            print(
                f"  {r['scenario']:5s} {r['method']:5s} rtol {r['rtol']:.1e}: l2 "
                f"{r['error_l2']:.2e}, {r['n_steps']} steps ({r['n_rejected']} rejected), "
                f"{r['n_rhs']} rhs, {r['n_lu']} LU, CPU {r['cpu_s'] * 1e3:.3f} ms (method "
                f"{r['method_cpu_s'] * 1e3:.3f} ms)"
            )


if __name__ == "__main__":
    main()
