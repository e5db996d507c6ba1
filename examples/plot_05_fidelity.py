"""
Fidelity levels and ``auto``
============================

One chain, several models of it: ``full`` (every unit's chamber, spring and threads),
and cheaper levels that leave something out (``quasi_static``: no inertia;
``grouped``: a few representative units stand for many; ``symmetric``: one unit for
all; see ``docs/numerics.md``). Each is a :func:`~sarcomere.dynamics.hanging_load` with
``fidelity=``; their error is measured here against ``full`` on a 30-unit chain.

A scene with ``fidelity = "auto"`` picks the level itself: ``full`` below 24 units, else
the cheapest reduced chain whose *predicted* error is within the tolerance (the rule is
deterministic, no clock). The packaged ``step-50g-n30-auto`` is such a scene.
"""

import tempfile
import time

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.dynamics import Step, hanging_load, simulate, solve_equilibrium
from sarcomere.scenarios import load_scenario, run

n, t_out = 30, np.linspace(0.0, 1.5, 301)
step = {"regulator.p_cmd": Step(final=0.1, time=0.1, unit="MPa")}
lengths, walls = {}, {}
for level in ("full", "grouped", "symmetric"):
    start = time.perf_counter()
    model = hanging_load(n=n, load_kg=0.05, fidelity=level)
    rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
    res = simulate(model, 1.5, inputs=step, x0=rest.x, t_out=t_out)
    walls[level] = time.perf_counter() - start
    lengths[level] = res["myofibril.length"]

stroke = lengths["full"][0] - lengths["full"].min()
fig, ax = plt.subplots(figsize=(6, 3.5))
for level, length in lengths.items():
    error = np.max(np.abs(length - lengths["full"])) / stroke
    print(f"{level:>10}: {walls[level]:.2f} s, error {100 * error:.2f} % of the stroke")
    ax.plot(t_out, length * 1e3, label=f"{level} ({walls[level]:.2f} s)")
ax.set_xlabel("time [s]")
ax.set_ylabel("chain length [mm]")
ax.set_title(f"{n} units, 50 g, 0.1 MPa step")
ax.legend()
fig.tight_layout()

# %%
# ``auto`` on the packaged 30-unit scene: the level it chose, and why (its predicted
# error against the tolerance), are in the run's output.

out = run(load_scenario("step-50g-n30-auto"), tempfile.mkdtemp(), quiet=True)
auto = out.extra["fidelity_auto"]
print(f"auto chose {out.fidelity!r}, tolerance {auto['tolerance']:.0%} of the stroke")
for level, error in auto["predicted_error"].items():
    if error is not None:
        print(f"  predicted error of {level}: {error:.1%}")
