"""
Constraints: a tension bound on every thread
============================================

The ``control-tension`` scene: a fast 6 mm shortening of a 20 g load, with every thread
tension to stay at or above 0.2 N (at rest the lowest thread carries 0.206 N). When a fast
shortening stops, the load's momentum carries it on up and unloads that thread: a
controller that does not know the bound breaks it. The NMPC states the bound at every
node of its horizon (``tension_min``, a soft constraint: the hard solution wherever that
is feasible); the LQI does not know it.
"""

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.dynamics import hanging_load

plant = hanging_load(n=3, load_kg=0.02)
op = operating_point(plant, {"regulator.p_cmd": 5e4})
y0, bound = op["myofibril.length"], 0.2  # m, N
task = {
    "output": "myofibril.length",
    "input": "regulator.p_cmd",
    "u_min": 0.0,
    "u_max": 3e5,
    "rate_max": 2e6,  # Pa/s
    "tension_min": bound,  # N, every thread; the MPCs use it, PID and LQI cannot
}


def reference(t):
    return y0 - 6e-3 if t >= 0.5 else y0


fig, (ax_y, ax_t) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
for slug in ("lqi", "nmpc"):
    controller = make_controller(slug, plant, op, 0.01, task)
    loop = run_closed_loop(
        plant,
        controller,
        op,
        reference,
        2.0,
        output="myofibril.length",
        tension_min=bound,
        preview=True,
    )
    res, m = loop.result, loop.metrics
    broken = m["tension_violation_max_mN"]
    print(f"{slug:>5}: bound broken by {broken:.1f} mN, rms error {m['rmse_mm']:.2f} mm")
    ax_y.plot(res.index, res["myofibril.length"] * 1e3, label=slug)
    ax_t.plot(res.index, res["myofibril.actin3.T"], label=slug)
t = np.linspace(0, 2, 201)
ax_y.plot(t, [reference(s) * 1e3 for s in t], "k:", label="reference")
ax_y.set_ylabel("length [mm]")
ax_y.legend()
ax_t.axhline(bound, color="r", ls="--", label="bound")
ax_t.set_ylabel("lowest thread [N]")
ax_t.set_xlabel("time [s]")
ax_t.legend()
fig.tight_layout()
