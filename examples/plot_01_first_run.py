"""
The first run: a 50 g step
==========================

The packaged scene ``step-50g``: a regulator step from 0 to 0.1 MPa at 0.1 s lifts 50 g
with a chain of three pneumatic sarcomere units. This is what
``sarcomere run step-50g --out out/step-50g`` runs; from Python, :func:`sarcomere.scenarios.run`
returns the same :class:`~sarcomere.scenarios.RunOutput` and writes the same files.
"""

import tempfile

import matplotlib.pyplot as plt

from sarcomere.scenarios import load_scenario, run

scene = load_scenario("step-50g")  # a packaged name, or the path of a TOML file
out = run(scene, tempfile.mkdtemp(), quiet=True)  # summary.json, timeseries.csv, PNGs
print(out.fidelity, out.solver)
for name, value in out.metrics.items():
    print(f"{name:>28} = {value:.6g}")

# %%
# The time series are a :class:`~sarcomere.dynamics.Result`, indexed by the variables'
# instance paths, in SI units.

res = out.results["main"]
fig, (ax_p, ax_l) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
ax_p.plot(res.index, res["regulator.p_cmd"] / 1e3, label="command")
ax_p.plot(res.index, res["myofibril.aps1.chamber.p_gauge"] / 1e3, label="chamber 1")
ax_p.set_ylabel("pressure [kPa]")
ax_p.legend()
ax_l.plot(res.index, res["myofibril.length"] * 1e3)
ax_l.set_ylabel("chain length [mm]")
ax_l.set_xlabel("time [s]")
fig.tight_layout()
