"""
Work-precision of the integrators
=================================

Every integrator of :data:`~sarcomere.dynamics.METHODS` runs the same 50 g step; each
point is one tolerance (adaptive methods) or one step size (fixed-step methods): the
error of the chain length against a tight-tolerance CVODES reference, against the wall
time. ``sarcomere bench work-precision`` is the full study (``docs/numerics.md``); here a
few points per method, short enough for a laptop.
"""

import time

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.dynamics import SolverSettings, Step, hanging_load, simulate, solve_equilibrium

model = hanging_load(n=3, load_kg=0.05)
rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
inputs = {"regulator.p_cmd": Step(final=1e5, time=0.1)}
t_out = np.linspace(0.0, 1.0, 201)


def run(settings):
    start = time.perf_counter()
    res = simulate(model, 1.0, inputs=inputs, x0=rest.x, settings=settings, t_out=t_out)
    return res["myofibril.length"], time.perf_counter() - start


reference, _ = run(SolverSettings("cvodes", rtol=1e-12, atol=1e-15))
simulate(model, 0.01, x0=rest.x, settings=SolverSettings("radau"))  # compile once (cached)

plans = {
    "cvodes": [SolverSettings("cvodes", rtol=r, atol=r * 1e-3) for r in (1e-4, 1e-6, 1e-8)],
    "radau": [SolverSettings("radau", rtol=r, atol=r * 1e-3) for r in (1e-4, 1e-6, 1e-8)],
    "scipy_bdf": [SolverSettings("scipy_bdf", rtol=r, atol=r * 1e-3) for r in (1e-4, 1e-6)],
    "rk4": [SolverSettings("rk4", step=h) for h in (2e-4, 1e-4, 5e-5)],
}
fig, ax = plt.subplots(figsize=(6, 4))
for method, settings in plans.items():
    points = []
    for s in settings:
        length, wall = run(s)
        points.append((wall, np.max(np.abs(length - reference))))
        print(f"{method:>10} {s.step or s.rtol:.0e}: {points[-1][1]:.2e} m, {wall:.3f} s")
    wall, err = np.array(points).T
    ax.loglog(err, wall, "o-", label=method)
ax.set_xlabel("max error of the chain length [m]")
ax.set_ylabel("wall time [s]")
ax.legend()
fig.tight_layout()
