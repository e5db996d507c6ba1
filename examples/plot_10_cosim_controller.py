"""
Co-simulation with a controller FMU
===================================

The muscle and its PID controller as two FMUs, coupled by the co-simulation master
(:func:`~sarcomere.fmu.cosimulate`): the controller FMU
(:func:`~sarcomere.fmu.controller.export_controller_fmu`) reads the muscle's length and
writes its regulator command every 10 ms, the same law as the Python
:class:`~sarcomere.controllers.pid.PID`. Archives are opened through
:func:`~sarcomere.fmu.open_fmu`, which checks an untrusted FMU before loading it. The
same loop run natively (:func:`~sarcomere.controllers.loop.run_closed_loop`) is the
reference.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.controllers import make_controller, operating_point
from sarcomere.controllers.loop import run_closed_loop
from sarcomere.dynamics import hanging_load
from sarcomere.fmu import Connection, FmuParticipant, cosimulate, export_fmu, open_fmu
from sarcomere.fmu.controller import export_controller_fmu

plant = hanging_load(n=3, load_kg=0.05)
op = operating_point(plant, {"regulator.p_cmd": 5e4})
y0, dt = op["myofibril.length"], 0.01
task = {"output": "myofibril.length", "input": "regulator.p_cmd", "u_min": 0.0, "u_max": 1e5}
pid = make_controller("pid", plant, op, dt, task)

folder = Path(tempfile.mkdtemp())
export_fmu(plant, folder / "muscle.fmu", 2, inputs={"regulator.p_cmd": 5e4})  # starts at rest
export_controller_fmu(pid, plant, folder / "pid.fmu", bias=5e4, fmi_version=2)


def reference(t):
    return y0 - 2e-3 if t >= 0.1 else y0


with open_fmu(folder / "muscle.fmu") as muscle, open_fmu(folder / "pid.fmu") as controller:
    cosim = cosimulate(
        [FmuParticipant(controller, "pid"), FmuParticipant(muscle, "muscle")],
        [
            Connection("pid.command", "muscle.regulator.p_cmd"),
            Connection("muscle.myofibril.length", "pid.measurement"),
        ],
        stop_time=1.5,
        step=dt,  # one controller sample per communication step
        ordering="gauss-seidel",  # the controller first, then the muscle on its command
        sources={"pid.reference": reference},
        record=["muscle.myofibril.length", "pid.command"],
    )

native = run_closed_loop(plant, pid, op, reference, 1.5, output="myofibril.length").result
difference = np.interp(cosim.index, native.index, native["myofibril.length"])
difference -= cosim["muscle.myofibril.length"]
print(f"co-simulation against the native loop: {np.max(np.abs(difference)):.2e} m")

fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
ax_y.plot(native.index, native["myofibril.length"] * 1e3, "k", lw=3, alpha=0.3, label="native")
ax_y.plot(cosim.index, cosim["muscle.myofibril.length"] * 1e3, "--", label="two FMUs")
ax_y.set_ylabel("length [mm]")
ax_y.legend()
ax_u.step(cosim.index, cosim["pid.command"] / 1e3, where="post")
ax_u.set_ylabel("PID FMU command [kPa]")
ax_u.set_xlabel("time [s]")
fig.tight_layout()
