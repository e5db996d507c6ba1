"""Why the fit engine uses IPOPT with the Gauss-Newton Hessian (docs/fitting.md, "Solver").

The same NLP (two parameters, regulator.tau and myofibril.tube1.C, of one APS under 50 g;
a 0.3 s step response at 1 ms, noise-free data from CVODES at rtol 1e-10; six shooting
intervals; start 30 % off) solved by IPOPT with the Gauss-Newton Hessian and by the
constrained Gauss-Newton (Levenberg-Marquardt-damped SQP, L1 merit) that was tried beside
it and deleted. Run from the repository root:

    git show d4eca6f:dynamics/identification/gauss_newton.py > /tmp/gauss_newton_d4eca6f.py
    .venv/bin/python benchmarks/fit_solver_choice.py

CPU time (time.process_time), each solver twice, interleaved.
"""

from __future__ import annotations

import importlib.util
import sys
import time

import casadi as cs
import numpy as np

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.identification.experiments import Estimated, Noise, TimeSeries
from sarcomere.dynamics.identification.problem import Problem
from sarcomere.dynamics.signals import Table
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

GN_FILE = "/tmp/gauss_newton_d4eca6f.py"


def main() -> None:
    spec = importlib.util.spec_from_file_location("gauss_newton_d4eca6f", GN_FILE)
    gnm = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = gnm
    spec.loader.exec_module(gnm)
    m = hanging_load(1, load_kg=0.05)
    C = "myofibril.tube1.C"
    truth = {"regulator.tau": 0.07, C: 1.4 * m.variables[C].value}
    t = np.arange(0, 0.3, 1e-3)
    u = np.where(t < 0.1, 0.0, 5e4)
    eq = solve_equilibrium(m, {"regulator.p_cmd": 0.0}, truth)
    law = Table(times=tuple(t), values=tuple(u), unit="Pa")
    res = simulate(
        m,
        t[-1],
        x0=eq.x,
        inputs={"regulator.p_cmd": law},
        params=truth,
        t_out=t,
        settings=SolverSettings(rtol=1e-10, atol=1e-12),
    )
    outs = ["myofibril.length", "myofibril.aps1.chamber.p_gauge"]
    data = np.column_stack([res[o] for o in outs])
    params = [
        Estimated("regulator.tau", "s", 0.05, 0.01, 0.5),
        Estimated(C, m.variables[C].unit, m.variables[C].value, 1e-12, 1e-6),
    ]
    uses = {"regulator.tau": ("regulator.tau", 1.0), C: (C, 1.0)}
    ts = TimeSeries("step", m, t, u[:, None], outs, data, m.parameters(), uses)
    pb = Problem(params, [ts], noise={outs[0]: Noise(1e-5), outs[1]: Noise(100.0)})
    v, w, rw, g, Jr = pb.nlp
    full = cs.Function("full", [v, w], [rw, Jr, g, cs.jacobian(g, v)])
    vals = cs.Function("vals", [v, w], [rw, g])
    v0 = pb.initial_guess(np.array([0.05, m.variables[C].value]))
    W, (lo, hi) = pb.weights(), pb.bounds()

    def f_full(x):
        r, J, gg, Jg = full(x, W)
        return np.array(r).ravel(), J.sparse(), np.array(gg).ravel(), Jg.sparse()

    def f_vals(x):
        return tuple(np.array(a).ravel() for a in vals(x, W))

    for _ in range(2):
        t0 = time.process_time()
        s = pb.solve(v0, W)
        print(
            f"IPOPT, Gauss-Newton Hessian: {s.status}, {s.iterations} iterations, "
            f"{time.process_time() - t0:.2f} s CPU, theta = {s.theta}"
        )
        t0 = time.process_time()
        out = gnm.gauss_newton(f_full, f_vals, v0, lo, hi, max_iter=100)
        print(
            f"constrained Gauss-Newton: {out.status}, {out.iterations} iterations, "
            f"{time.process_time() - t0:.2f} s CPU, theta = {pb.values(out.v[:2])}"
        )
    print(f"truth: {list(truth.values())}")


if __name__ == "__main__":
    main()
