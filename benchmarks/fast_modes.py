"""Where removing fast modes pays: each fidelity level's stiffness, the explicit RK4 step
it allows and what a run costs with RK4 (at the largest stable step), the compiled Radau
IIA and CVODES, side by side in one process.

Scene: ``hanging_load`` with 50 g, the command stepping 0 -> 0.1 MPa at 0.1 s, 2 s, 201
output points (the speed benchmark's scene), at n = 3 (full, quasi_static, symmetric) and
n = 10 (full, quasi_static, grouped, symmetric), both with the instant-pneumatics levels
(instant_pneumatics, instant_quasi_static: the chambers at the regulator's pressure, no
0.37 ms filling mode). Per level: the largest |lambda| of the
exact Jacobian at the start and final equilibria, RK4's stability limit from them
(:func:`~sarcomere.dynamics.simulation.guard.max_stable_step`), an RK4 run at 0.9 of that
limit (rounded down so the output spacing is a whole number of steps), with its stability
guard (the eigenvalues at the start and at the equilibrium after the step, as ``simulate``
runs it) and without (``rk4_unguarded``: the steps alone), ``radau`` and
``cvodes`` at rtol 1e-6; the error of each run is ``max |L - L_full| / span(L_full)`` of
``myofibril.length`` against full at CVODES rtol 1e-10 (so it holds the level's own
modelling error and the method's), the time the median of ``--repeats`` warm calls.

``--mpc``: the RTI NMPC of ``sarcomere bench mpc`` (:mod:`sarcomere.scenarios.studies.mpc_speed`:
n = 3, 20 g, horizon 20, 10 ms, its Radau collocation) with each level as the prediction
model on the full plant: time per step, tracking error and the raised tension bound.

Usage::

    python benchmarks/fast_modes.py --out out/bench/fast_modes.json [--repeats 5] [--mpc]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import numpy as np

from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.dynamics import SolverSettings, hanging_load, simulate, solve_equilibrium
from sarcomere.dynamics.signals import Step
from sarcomere.dynamics.simulation.guard import RK4, jacobian_eigenvalues, max_stable_step
from sarcomere.scenarios.studies import mpc_speed as mpc_study
from sarcomere.scenarios.threads import limited_blas

STOP_S = 2.0
DT_OUT_S = 0.01
INPUTS = {"regulator.p_cmd": Step(final=1e5, time=0.1, unit="Pa")}
INSTANT = ("instant_pneumatics", "instant_quasi_static")
CASES = {
    3: ("full", "quasi_static", "symmetric", *INSTANT),
    10: ("full", "quasi_static", "grouped", "symmetric", *INSTANT),
}
MPC_LEVELS = ("full", "quasi_static", *INSTANT)
METHODS = ("rk4", "rk4_unguarded", "radau", "cvodes")


def _largest_eigenvalue(model) -> float:
    """max |lambda| [1/s] of the exact Jacobian at the 0 and 0.1 MPa equilibria."""
    top = 0.0
    for p_cmd in (0.0, 1e5):
        eq = solve_equilibrium(model, {"regulator.p_cmd": p_cmd})
        top = max(top, float(np.max(np.abs(jacobian_eigenvalues(model, eq.x, eq.u, eq.p)))))
    return top


def _stable_rk4_step(model) -> tuple[float, float]:
    """(RK4's limit [s] over both equilibria, the step used: 0.9 of it, a divisor of the
    output spacing)."""
    limit = math.inf
    for p_cmd in (0.0, 1e5):
        eq = solve_equilibrium(model, {"regulator.p_cmd": p_cmd})
        lam = jacobian_eigenvalues(model, eq.x, eq.u, eq.p)
        limit = min(limit, max_stable_step(lam, RK4)[0])
    per_output = math.ceil(DT_OUT_S / (0.9 * limit))
    return limit, DT_OUT_S / per_output


def _timed(model, settings, x0, repeats) -> tuple[float, object]:
    def run():
        return simulate(
            model,
            STOP_S,
            INPUTS,
            x0=x0,
            settings=settings,
            output_interval=DT_OUT_S,
            signals=["myofibril.length"],
        )

    res = run()  # cold: builds and caches (radau compiles here)
    times = []
    for _ in range(repeats):
        tic = time.perf_counter()
        res = run()
        times.append(time.perf_counter() - tic)
    return statistics.median(times), res


def study(repeats: int) -> dict:
    rows: dict = {}
    for n, levels in CASES.items():
        full = hanging_load(n, load_kg=0.05)
        x0_full = solve_equilibrium(full, {"regulator.p_cmd": 0.0}).x
        ref = simulate(
            full,
            STOP_S,
            INPUTS,
            x0=x0_full,
            settings=SolverSettings(rtol=1e-10, atol=1e-14),
            output_interval=DT_OUT_S,
            signals=["myofibril.length"],
        )["myofibril.length"]
        span = float(np.ptp(ref))
        for level in levels:
            model = hanging_load(n, load_kg=0.05, fidelity=level)
            x0 = solve_equilibrium(model, {"regulator.p_cmd": 0.0}).x
            limit, h = _stable_rk4_step(model)
            row = {
                "n": n,
                "level": level,
                "nx": model.nx,
                "max_abs_eig_per_s": _largest_eigenvalue(model),
                "rk4_limit_s": limit,
                "rk4_step_s": h,
            }
            for name, settings in (
                ("rk4", SolverSettings(method="rk4", step=h, max_steps=10_000_000)),
                (
                    "rk4_unguarded",
                    SolverSettings(
                        method="rk4",
                        step=h,
                        max_steps=10_000_000,
                        options=(("on_unstable", "ignore"),),
                    ),
                ),
                ("radau", SolverSettings(method="radau", rtol=1e-6, atol=1e-9)),
                ("cvodes", SolverSettings(method="cvodes", rtol=1e-6, atol=1e-9)),
            ):
                wall, res = _timed(model, settings, x0, repeats)
                err = float(np.max(np.abs(res["myofibril.length"] - ref))) / span
                row[name] = {
                    "wall_ms": wall * 1e3,
                    "error_vs_full": err,
                    "steps": res.meta.get("n_steps"),
                }
            rows[f"n{n}-{level}"] = row
            print(
                f"n={n:3d} {level:13s} nx {model.nx:3d} |lam| {row['max_abs_eig_per_s']:9.0f} "
                f"rk4 h {h * 1e3:7.4f} ms: "
                + "  ".join(
                    f"{k} {row[k]['wall_ms']:7.1f} ms err {row[k]['error_vs_full']:8.1e}"
                    for k in METHODS
                ),
                flush=True,
            )
    return rows


def mpc_prediction() -> dict:
    """The RTI NMPC with each of :data:`MPC_LEVELS` as its prediction model, on the full
    plant of the MPC study's length-control scene and its venting scene."""
    rows = {}
    settings = NMPCSettings(horizon=mpc_study.HORIZON)
    for level in MPC_LEVELS:
        model = mpc_study._prediction(level)
        runs = [
            mpc_study.run_scene(
                lambda eq, m=model: NonlinearMPC(m, eq.u, mpc_study.DT, settings), quick=False
            )
            for _ in range(mpc_study.FAST_REPEATS)
        ]
        best = min(runs, key=lambda r: r["step_median_ms"])
        keep = ("step_median_ms", "step_p95_ms", "rmse_mm", "rmse_before_load_mm", "fallbacks")
        rows[level] = {"nx": model.nx, **{k: best[k] for k in keep}}
        rows[level] |= mpc_study.tension_scene(level)
        r = rows[level]
        print(
            f"mpc {level:22s} nx {model.nx:3d} step {r['step_median_ms']:6.2f} ms "
            f"(p95 {r['step_p95_ms']:6.2f}) rmse {r['rmse_mm']:.3f} mm "
            f"(before load {r['rmse_before_load_mm']:.3f}) lowest T {r['lowest_tension_N']:.4f} N",
            flush=True,
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/fast_modes.json"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--mpc", action="store_true", help="also the NMPC prediction levels")
    args = parser.parse_args()
    with limited_blas():
        rows = study(args.repeats)
        if args.mpc:
            rows["mpc_prediction"] = mpc_prediction()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
