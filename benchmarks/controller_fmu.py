"""Speed of the NMPC (or LMPC) controller FMU against the Python controller it is
generated from.

The set-up of the control scenes: the plant ``hanging_load(n, 20 g)`` (exact flow law), the
NMPC's prediction the same set-up with the smooth flow law and no clamp, real-time
iteration, horizon 20, 10 ms samples (``--controller lmpc``: the LMPC on the plant model,
horizon 20, no disturbance filter, kept at its linearisation: what its FMU holds). The
Python controller runs a closed loop on the plant
(length steps of -2 and +3 mm, ``--samples`` samples) and records what it read; the
exported FMU (FMI 2.0) is then stepped through the same measurements with fmpy
(``doStep`` of one sample each). Reported, in one process: the median ``doStep`` time
[ms] (timed around ``doStep`` alone), the median ``NonlinearMPC.update`` time, their
ratio, the largest command difference [Pa], the export time.

Usage::

    python benchmarks/controller_fmu.py --out out/bench/controller_fmu.json [--n 3]
        [--linear-solver sparse_lu qr]   # the NMPC law's lifted solver(s), one run each
    python benchmarks/controller_fmu.py --controller lmpc
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.rti import GENERATED_SOLVERS
from sarcomere.dynamics import hanging_load, solve_equilibrium
from sarcomere.dynamics.simulation.simulator import Simulator
from sarcomere.fmu.controller import export_controller_fmu

DT = 0.01
"""Sample time [s]."""
U0 = 5e4
"""Start command [Pa]."""


def closed_loop(plant, nmpc, op, samples: int) -> tuple[list, list, list, list]:
    """The Python NMPC on the plant: what it read, the references, its commands and the
    time of each ``update`` [s]."""
    sim = Simulator(plant)
    sim.reset(op.x, op.z, None, 0.0)
    y0, out = op["myofibril.length"], nmpc.settings.output
    nmpc.reset({"regulator.p_cmd": U0})
    read, refs, cmds, times = [], [], [], []
    for k in range(samples):
        t = k * DT
        r = y0 - (2e-3 if t >= 0.1 else 0.0) + (3e-3 if t >= 1.0 else 0.0)
        y = sim.signals(nmpc.outputs)
        start = time.perf_counter()
        u = nmpc.update(t, y, {out: r})
        times.append(time.perf_counter() - start)
        read.append(y), refs.append(r), cmds.append(u["regulator.p_cmd"])
        sim.step(u, DT)
    return read, refs, cmds, times


def fmu_steps(path: Path, folder: str, nmpc, read, refs, ident: str) -> tuple[list, list]:
    """The FMU stepped once per sample on the recorded signals: commands, doStep times."""
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=ident, instanceName="b")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    names = ["reference", "measurement", *nmpc.model.state_names]
    refs_vr = [vr[n] for n in names]
    out = nmpc.settings.output
    cmds, times = [], []
    for k, (y, r) in enumerate(zip(read, refs, strict=True)):
        s.setReal(refs_vr, [r, y[out], *(y[n] for n in nmpc.model.state_names)])
        start = time.perf_counter()
        s.doStep(k * DT, DT)
        times.append(time.perf_counter() - start)
        cmds.append(s.getReal([vr["command"]])[0])
    s.terminate()
    s.freeInstance()
    return cmds, times


def measure(plant, pred, op, args, linear_solver: str) -> dict:
    """One controller's closed loop, its FMU's export and steps; the results."""
    if args.controller == "nmpc":
        s = NMPCSettings(linear_solver=linear_solver)
        nmpc = NonlinearMPC(pred, op.u, DT, s)
    else:  # re-linearisation out of reach: the FMU keeps the linearisation
        fixed = LMPCSettings(disturbance="none", relinearize_m=1.0, relinearize_x=1e6)
        nmpc = LinearMPC(plant, op.x, op.u, DT, fixed)
    read, refs, want, py_times = closed_loop(plant, nmpc, op, args.samples)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        path = export_controller_fmu(nmpc, plant, Path(tmp) / f"{args.controller}.fmu", U0, 2)
        export_s = time.perf_counter() - start
        folder = extract(str(path), unzipdir=f"{tmp}/x")
        got, fmu_times = fmu_steps(path, folder, nmpc, read, refs, args.controller)
    res = {
        "controller": args.controller,
        "linear_solver": linear_solver if args.controller == "nmpc" else None,
        "n": args.n,
        "horizon": nmpc.settings.horizon,
        "samples": args.samples,
        "states": plant.nx,
        "memory": nmpc.law_function().nnz_in(0),
        "export_s": export_s,
        "fmu_doStep_median_ms": 1e3 * statistics.median(fmu_times),
        "python_update_median_ms": 1e3 * statistics.median(py_times),
        "max_command_difference_Pa": float(np.max(np.abs(np.subtract(got, want)))),
        "fallbacks": nmpc.stats.fallbacks,
        "commands": want,
    }
    res["ratio_python_over_fmu"] = res["python_update_median_ms"] / res["fmu_doStep_median_ms"]
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=3, help="APS in the chain")
    ap.add_argument("--samples", type=int, default=200, help="samples of the scene")
    ap.add_argument("--controller", choices=("nmpc", "lmpc"), default="nmpc")
    ap.add_argument(
        "--linear-solver",
        nargs="+",
        choices=GENERATED_SOLVERS,
        default=list(GENERATED_SOLVERS)[::-1],
        help="the NMPC law's lifted solver(s), each measured in this process",
    )
    ap.add_argument("--out", type=Path, help="JSON file of the results")
    args = ap.parse_args()
    plant = hanging_load(args.n, load_kg=0.02)
    pred = hanging_load(args.n, load_kg=0.02, flow_law="smooth", saturate=False)
    op = solve_equilibrium(plant, {"regulator.p_cmd": U0})
    solvers = args.linear_solver if args.controller == "nmpc" else [None]
    runs = [measure(plant, pred, op, args, ls) for ls in solvers]
    first = runs[0].pop("commands")
    for r in runs[1:]:  # the same closed loop with another solver: its commands' distance
        r["max_command_difference_to_first_Pa"] = float(
            np.max(np.abs(np.subtract(r.pop("commands"), first)))
        )
    res = runs[0] if len(runs) == 1 else {"runs": runs}
    print(json.dumps(res, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
