"""
PID, LQI and NMPC on the length
===============================

Three controllers of :mod:`sarcomere.controllers` track the chain's length with the
regulator command, each built by :func:`~sarcomere.controllers.make_controller` from the
same task (the ``control-length`` scene's: 3 units, 20 g, 50 kPa, commands within
0-0.3 MPa, sampled every 10 ms) and run on the nonlinear plant by
:func:`~sarcomere.controllers.loop.run_closed_loop`: a 1.5 mm step, then a 1 Hz sine.
The NMPC (:class:`~sarcomere.controllers.nmpc.NonlinearMPC`) predicts with the model's
own equations and sees the reference over its horizon.
"""

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.dynamics import hanging_load

plant = hanging_load(n=3, load_kg=0.02)
op = operating_point(plant, {"regulator.p_cmd": 5e4})
y0 = op["myofibril.length"]
task = {
    "output": "myofibril.length",
    "input": "regulator.p_cmd",
    "u_min": 0.0,
    "u_max": 3e5,
    "rate_max": 2e6,  # Pa/s
}


def reference(t):
    step = -1.5e-3 if t >= 0.5 else 0.0
    sine = 1e-3 * np.sin(2 * np.pi * (t - 2.0)) if t >= 2.0 else 0.0
    return y0 + step + sine


fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
for slug in ("pid", "lqi", "nmpc"):
    controller = make_controller(slug, plant, op, 0.01, task)
    loop = run_closed_loop(
        plant, controller, op, reference, 4.0, output="myofibril.length", preview=True
    )
    res = loop.result
    m = loop.metrics
    ms = m["solve_time_median_ms"]
    print(f"{slug:>5}: {loop.status}, rms error {m['rmse_mm']:.3f} mm, {ms:.3f} ms a sample")
    ax_y.plot(res.index, res["myofibril.length"] * 1e3, label=slug)
    ax_u.plot(res.index, res["regulator.p_cmd"] / 1e3, label=slug)
t = np.linspace(0, 4, 401)
ax_y.plot(t, [reference(s) * 1e3 for s in t], "k:", label="reference")
ax_y.set_ylabel("length [mm]")
ax_y.legend(ncol=4)
ax_u.set_ylabel("command [kPa]")
ax_u.set_xlabel("time [s]")
fig.tight_layout()
