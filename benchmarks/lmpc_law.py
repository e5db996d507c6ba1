"""The linear MPC's law on the control-length scene: one update, and the QP three ways.

Runs the packaged ``control-length`` scene with its ``lmpc`` entry only (3 APS, horizon
20, 10 ms, the scene's limits and noise), recording the arguments of every sample's law
call, then replays them in the same process, interleaved sample by sample:

* ``law_daqp``: :meth:`LinearMPC.law_function` with DAQP, what ``update`` evaluates;
* ``law_qrqp``: the same Function with qrqp, the one the controller FMU compiles
  (interpreted here; the first ``--qrqp`` samples only, it is slow);
* ``conic_per_sample``: the former path, :meth:`VelocityQP.solve` (numpy around a
  ``casadi.conic`` DAQP call) on the same condensed QP.

Usage::

    python benchmarks/lmpc_law.py --out out/bench/lmpc_law [--qrqp 100]

prints medians and writes ``lmpc_law.json``. Times are wall-clock per call [ms]; the scene's
own ``lmpc_solve_time_median_ms`` (whole ``update``: filter, re-linearisation check, law)
is reported alongside.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from sarcomere.controllers import lmpc as lmpc_module
from sarcomere.controllers.qp import qp_solver
from sarcomere.scenarios.runner import run


def record_scene(out: Path) -> tuple[list, object, dict]:
    """Run control-length with its lmpc only; the law's arguments of every sample."""
    text = resources.files("sarcomere.scenarios").joinpath("control-length.toml").read_text()
    keep = re.sub(r"\[control\.controllers\.(?!lmpc\])\w+\]\n(\w.*\n)*", "", text)
    calls = []
    original = lmpc_module._Buffered.__call__

    def recorded(self, *args):
        calls.append((self, [np.array(a, dtype=float) for a in args]))
        return original(self, *args)

    lmpc_module._Buffered.__call__ = recorded
    try:
        with tempfile.TemporaryDirectory() as tmp:
            scene = Path(tmp) / "control-length-lmpc.toml"
            scene.write_text(keep)
            result = run(str(scene), out, quiet=True)
    finally:
        lmpc_module._Buffered.__call__ = original
    made = {id(c[0]): c[0] for c in calls}
    if len(made) != 1:
        raise RuntimeError(f"expected one LMPC law, found {len(made)}")
    return [a for _, a in calls], next(iter(made.values())), result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--qrqp", type=int, default=100, help="samples replayed with qrqp")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    calls, law, result = record_scene(args.out)
    F = law.function
    N = F.nnz_in(3) - 1  # ref: now and the horizon's nodes
    nx = F.nnz_in(0) - 1 - N  # memory: x_prev, started, plan (one input)
    ns = F.nnz_in(1) - nx - 1
    qrqp = lmpc_module._Buffered(lmpc_module.velocity_law(nx, 1, ns, N, "qrqp"))
    daqp = lmpc_module._Buffered(lmpc_module.velocity_law(nx, 1, ns, N, "daqp"))
    times = {"law_daqp": [], "law_qrqp": [], "conic_per_sample": []}
    du_diff, qp_cache = [], {}
    for k, (mem, x, u_prev, ref, p) in enumerate(calls):
        tic = time.perf_counter()
        _, u, ok = daqp(mem, x, u_prev, ref, p)
        times["law_daqp"].append(time.perf_counter() - tic)
        if k < args.qrqp:
            tic = time.perf_counter()
            _, u_q, _ = qrqp(mem, x, u_prev, ref, p)
            times["law_qrqp"].append(time.perf_counter() - tic)
            du_diff.append(abs(float(u_q[0]) - float(u[0])))
        # the former path: numpy around a conic call on the same QP data
        key = p.tobytes()
        if key not in qp_cache:
            qp_cache.clear()
            qp_cache[key] = _velocity_qp(p, nx, ns, N)
        qp, solver = qp_cache[key]
        started = mem[nx] > 0
        tic = time.perf_counter()
        dx = x[:nx] - mem[:nx] if started else np.zeros(nx)
        xi0 = np.concatenate([dx, [x[nx] - ref[0]]])
        lo, hi, dmax, smin = _bounds(p, ns)
        qp.solve(xi0, u_prev, lo, hi, dmax, smin - x[nx + 1 :], ref[1:] - ref[0])
        times["conic_per_sample"].append(time.perf_counter() - tic)
    med = {k: statistics.median(v) * 1e3 for k, v in times.items() if v}
    report = {
        "samples": len(calls),
        "median_ms": med,
        "p95_ms": {k: float(np.percentile(v, 95)) * 1e3 for k, v in times.items() if v},
        "qrqp_samples": len(times["law_qrqp"]),
        "qrqp_vs_daqp_max_command_difference_Pa": max(du_diff) if du_diff else None,
        "scene_update_median_ms": result.metrics["lmpc_solve_time_median_ms"],
        "scene_update_p95_ms": result.metrics["lmpc_solve_time_p95_ms"],
        "scene_rmse_mm": result.metrics["lmpc_rmse_mm"],
        "ratio_conic_over_law_daqp": med["conic_per_sample"] / med["law_daqp"],
    }
    (args.out / "lmpc_law.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0


def _sizes(nx: int, ns: int, N: int) -> list[int]:
    nq, nv, na = N, N + ns, N * (1 + ns)
    return [nv * nv, nq * (nx + 1), nq * N, na * nv, N * ns * (nx + 1), 1, 1, 1, 1, 1, ns]


def _split(p: np.ndarray, nx: int, ns: int, N: int) -> list[np.ndarray]:
    return np.split(p, np.cumsum(_sizes(nx, ns, N))[:-1])


def _bounds(p: np.ndarray, ns: int):
    tail = p[len(p) - (3 + ns) :]
    return tail[:1], tail[1:2], tail[2:3], tail[3:]


def _velocity_qp(p: np.ndarray, nx: int, ns: int, N: int):
    """A :class:`VelocityQP` carrying the law's condensed data (no re-condensing)."""
    H, G, Gr, A, Ssx, us, ws, *_ = _split(p, nx, ns, N)
    nv, na = N + ns, N * (1 + ns)
    qp = object.__new__(lmpc_module.VelocityQP)
    qp.horizon, qp.nu, qp.ns, qp.weight_slack = N, 1, ns, float(ws[0])
    qp.u_scale = us
    qp.H = H.reshape(nv, nv, order="F")
    qp._G = G.reshape(N, nx + 1, order="F")
    qp._Gr = Gr.reshape(N, N, order="F")
    qp.A = A.reshape(na, nv, order="F")
    qp._Ssx = Ssx.reshape(N * ns, nx + 1, order="F")
    qp.solver = qp_solver("daqp", *qp.sparsities())
    return qp, qp.solver


if __name__ == "__main__":
    raise SystemExit(main())
