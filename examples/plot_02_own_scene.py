"""
Your own scene, from Python
===========================

A scene is data: the tables of a scenario TOML file (``docs/scenarios.md``), here a
string checked by :func:`~sarcomere.scenarios.parse_scenario` (every dimensioned quantity
with its unit; a wrong key or unit is refused with its name and line). Five units lift 100 g under a
pressure ramp, integrated by the compiled Radau IIA.

The same model can be built without a scene: :func:`~sarcomere.dynamics.hanging_load`
and :func:`~sarcomere.dynamics.simulate`, as in the second half.
"""

import tempfile

import matplotlib.pyplot as plt

from sarcomere.dynamics import Ramp, hanging_load, simulate, solve_equilibrium
from sarcomere.scenarios import parse_scenario, run

text = """
[scenario]
name = "ramp-100g-n5"
kind = "transient"
description = "five units lift 100 g under a 0 -> 0.12 MPa ramp"

[model]
name = "myofibril"
n = 5
[model.options]
setup = "hanging"
load = "100 g"

[inputs.pressure]
type = "ramp"
start = "0.1 s"
duration = "1 s"
final = "0.12 MPa"

[simulation]
stop_time = "1.5 s"
output_interval = "5 ms"

[solver]
method = "radau"
"""
scene = parse_scenario(text, "ramp-100g-n5.toml")
out = run(scene, tempfile.mkdtemp(), quiet=True)
print({k: round(v, 4) for k, v in out.metrics.items()})
scene_result = out.results["main"]

# %%
# The same experiment on the model directly: a flattened CasADi model with named
# variables, its rest state, and a simulation with an input signal that carries its unit.

model = hanging_load(n=5, load_kg="100 g")
rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
ramp = Ramp(final=0.12, start=0.1, duration=1.0, unit="MPa")
res = simulate(model, 1.5, inputs={"regulator.p_cmd": ramp}, x0=rest.x, output_interval=5e-3)

fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(scene_result.index, scene_result["myofibril.length"] * 1e3, label="scene (radau)")
ax.plot(res.index, res["myofibril.length"] * 1e3, "--", label="simulate (cvodes)")
ax.set_xlabel("time [s]")
ax.set_ylabel("chain length [mm]")
ax.legend()
fig.tight_layout()
