"""The linear MPC's law on the control-length scene: one update, and the QP two ways.

Runs the packaged ``control-length`` scene with its ``lmpc`` entry only (3 APS, horizon
20, 10 ms, the scene's limits and noise), recording the arguments of every sample's law
call, then replays them in the same process, interleaved sample by sample:

* ``law_daqp``: :meth:`LinearMPC.law_function` with DAQP, what ``update`` evaluates;
* ``law_qrqp``: the same Function with qrqp, the one the controller FMU compiles
  (interpreted here; the first ``--qrqp`` samples only, it is slow).

The third way of BENCHMARKS.md section 9, ``conic_per_sample`` (numpy around a
``casadi.conic`` call, ``VelocityQP.solve``), was deleted with that copy of the QP in
issue 23: the law above is the one the controller runs and the tests test.

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
from sarcomere.controllers.qp import velocity_law
from sarcomere.dynamics.modeling.buffered import BufferedCall
from sarcomere.scenarios.runner import run


def record_scene(out: Path) -> tuple[list, object, dict]:
    """Run control-length with its lmpc only; the law's arguments of every sample."""
    text = resources.files("sarcomere.scenarios").joinpath("control-length.toml").read_text()
    keep = re.sub(r"\[control\.controllers\.(?!lmpc\])\w+\]\n(\w.*\n)*", "", text)
    calls = []

    class Recorded(BufferedCall):  # the LMPC builds its law with this name
        def outputs(self, *args):
            calls.append((self, [np.array(a, dtype=float) for a in args]))
            return super().outputs(*args)

    lmpc_module.BufferedCall = Recorded
    try:
        with tempfile.TemporaryDirectory() as tmp:
            scene = Path(tmp) / "control-length-lmpc.toml"
            scene.write_text(keep)
            result = run(str(scene), out, quiet=True)
    finally:
        lmpc_module.BufferedCall = BufferedCall
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
    qrqp = BufferedCall(velocity_law(nx, 1, ns, N, "qrqp"))
    daqp = BufferedCall(velocity_law(nx, 1, ns, N, "daqp"))
    times = {"law_daqp": [], "law_qrqp": []}
    du_diff = []
    for k, (mem, x, u_prev, ref, p) in enumerate(calls):
        tic = time.perf_counter()
        _, u, ok = daqp.outputs(mem, x, u_prev, ref, p)
        times["law_daqp"].append(time.perf_counter() - tic)
        if k < args.qrqp:
            tic = time.perf_counter()
            _, u_q, _ = qrqp.outputs(mem, x, u_prev, ref, p)
            times["law_qrqp"].append(time.perf_counter() - tic)
            du_diff.append(abs(float(u_q[0]) - float(u[0])))
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
    }
    (args.out / "lmpc_law.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
