"""
The paper's static model against the dynamic one
================================================

The source paper models one unit statically: pressure -> expansion force of the soft
chamber -> thread angle -> contraction force (:func:`~sarcomere.dynamics.paper.paper_static`,
its equations as printed with the corrections of ``docs/paper.md``). The dynamic model
builds the same unit from components (chamber, Yeoh spring, threads, tube, regulator) and
finds its equilibria by Newton; between equilibria it moves in time.

Here both give the isometric force of one unit held at its rest length (the paper's
Fig. 8D), against the paper's measurement at 0.1 MPa; then the dynamic model's force
after a pressure step, which the static model cannot give.
"""

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.dynamics import Step, isometric, simulate, solve_equilibrium
from sarcomere.dynamics.paper import PaperOptions, paper_static
from sarcomere.dynamics.params import experimental_geometry

pressures = np.linspace(0.01e6, 0.1e6, 10)  # Pa, gauge
options = PaperOptions(force_scale=1e-3, theta="corrected", kinematics="triangle", use_tan=True)
paper = paper_static(pressures, experimental_geometry(), "dragonskin_30", options)

model = isometric(n=1)
dynamic = [solve_equilibrium(model, {"regulator.p_cmd": p})["sensor.f"] for p in pressures]

fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(pressures / 1e3, paper.F_spa_N, "o-", label="paper, static: $F_{SPA}$")
ax.plot(pressures / 1e3, paper.F_contr_N, "s-", label=r"paper, static: $F_{SPA}\tan\theta$")
ax.plot(pressures / 1e3, dynamic, "k^-", label="dynamic model, equilibrium")
ax.plot([100], [0.315], "r*", ms=12, label="measured (paper)")
ax.set_xlabel("gauge pressure [kPa]")
ax.set_ylabel("isometric force [N]")
ax.legend()
fig.tight_layout()

# %%
# The dynamic model in time: a step to 0.1 MPa at 0.1 s. The force follows the chamber's
# pressure, filled through the regulator and the tube, and settles on the equilibrium
# above.

rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
res = simulate(
    model, 1.0, inputs={"regulator.p_cmd": Step(final=0.1, time=0.1, unit="MPa")}, x0=rest.x
)
print(f"force after 1 s: {res.final('sensor.f'):.4f} N, equilibrium: {dynamic[-1]:.4f} N")

fig, ax = plt.subplots(figsize=(6, 3))
ax.plot(res.index, res["sensor.f"])
ax.axhline(dynamic[-1], color="k", ls=":", label="equilibrium at 0.1 MPa")
ax.set_xlabel("time [s]")
ax.set_ylabel("sensor force [N]")
ax.legend()
fig.tight_layout()
