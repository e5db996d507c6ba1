"""
Export an FMU and simulate it in fmpy
=====================================

:func:`~sarcomere.fmu.export_fmu` writes the flattened model as one FMU (FMI 2.0 or 3.0,
Model Exchange and Co-Simulation in one archive, self-contained generated C compiled on
this machine). Any FMI tool runs it; here `fmpy <https://github.com/CATIA-Systems/FMPy>`_,
in both interfaces, against the library's own simulation of the same step.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from fmpy import simulate_fmu

from sarcomere.dynamics import Step, hanging_load, simulate, solve_equilibrium
from sarcomere.fmu import Experiment, export_fmu

model = hanging_load(n=3, load_kg=0.05)
path = Path(tempfile.mkdtemp()) / "h3.fmu"
export_fmu(model, path, fmi_version=2, experiment=Experiment(stop_time=2.0, step_size=1e-3))

step = np.array(
    [(0.0, 0.0), (0.1, 0.0), (0.1, 1e5), (2.0, 1e5)],
    dtype=[("time", float), ("regulator.p_cmd", float)],
)
runs = {
    interface: simulate_fmu(
        str(path),
        fmi_type=interface,
        stop_time=2.0,
        output_interval=2e-3,
        input=step,
        output=["myofibril.length"],
    )
    for interface in ("CoSimulation", "ModelExchange")
}

rest = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
native = simulate(model, 2.0, inputs={"regulator.p_cmd": Step(final=1e5, time=0.1)}, x0=rest.x)

fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(native.index, native["myofibril.length"] * 1e3, "k", lw=3, alpha=0.3, label="simulate")
for interface, rec in runs.items():
    ax.plot(rec["time"], rec["myofibril.length"] * 1e3, "--", label=f"fmpy, {interface}")
    error = np.max(
        np.abs(
            np.interp(native.index, rec["time"], rec["myofibril.length"])
            - native["myofibril.length"]
        )
    )
    print(f"{interface}: max difference from simulate {error:.2e} m")
ax.set_xlabel("time [s]")
ax.set_ylabel("chain length [mm]")
ax.legend()
fig.tight_layout()
