"""
Stepping the simulator yourself
===============================

:func:`~sarcomere.dynamics.simulate` runs a whole experiment; a
:class:`~sarcomere.dynamics.Simulator` is stepped by your own loop (a controller, a
co-simulation master), with a new held input every step and the same integrators. Here a
bang-bang rule holds the chain near 176 mm: full pressure while it is longer, vent while
it is shorter. The regulator's lag and the chamber's filling make it oscillate about the
switching point.
"""

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.dynamics import Simulator, SolverSettings, hanging_load, solve_equilibrium

model = hanging_load(n=3, load_kg=0.05)
rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
sim = Simulator(model, SolverSettings("radau"))
sim.reset(x0=rest.x)

t, length, command = [], [], []
for _ in range(200):  # 10 ms samples
    p_cmd = 1e5 if sim.signal("myofibril.length") > 0.176 else 0.0
    t.append(sim.t)
    length.append(sim.signal("myofibril.length"))
    command.append(p_cmd)
    sim.step({"regulator.p_cmd": p_cmd}, 0.01)
print(f"after {sim.t:.2f} s: {1e3 * sim.signal('myofibril.length'):.2f} mm")

fig, (ax_l, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(6, 4.5))
ax_l.plot(t, np.array(length) * 1e3)
ax_l.axhline(176, color="k", ls=":")
ax_l.set_ylabel("length [mm]")
ax_u.step(t, np.array(command) / 1e3, where="post")
ax_u.set_ylabel("command [kPa]")
ax_u.set_xlabel("time [s]")
fig.tight_layout()
