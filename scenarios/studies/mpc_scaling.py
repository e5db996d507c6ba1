"""The RTI NMPC's cost against the chain length n (``python benchmarks/mpc.py --scaling``).

For each n: the RTI with the dense lift uncompiled (LAPACK's LU of every sensitivity:
``linear_solver = "lapacklu"``), the same lift solved by the bordered banded LU
(``"banded"``, what the default builds uncompiled), the kept sparse factors uncompiled
(``"sparse_lu"``) and compiled (``compiled = true``: the factored lift's
small per-interval Functions generated to C); the build's wall time, its CPU time and
the compiler's (``RUSAGE_CHILDREN``). Then they run interleaved, sample by sample, on
one closed loop (the plant: the full exact-law chain with 20 g, CVODES between samples;
it follows the dense one's commands, the others get the same measurements): a 3 mm
shorter step, then a 1 mm longer one. Per variant the medians of the CPU time
(``time.thread_time``) of the whole ``Controller.checked`` call and of its three
Functions (preparation, feedback, update), and the largest command difference to the
dense one [Pa]. A variant the controller refuses (``"banded"`` where the band does not pay)
is recorded with the refusal. CPU time and side-by-side ratios: the machine may be shared.
"""

from __future__ import annotations

import resource
import time

import numpy as np

from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.simulation.simulator import Simulator

from .mpc_speed import DT, HORIZON, L_NAME, LOAD_KG, P_NAME, P_START, Timed

VARIANTS = {
    "python_dense": {"linear_solver": "lapacklu"},
    "python_banded": {"linear_solver": "banded"},
    "python_factored": {"linear_solver": "sparse_lu"},
    "compiled": {"compiled": True},
}
"""The RTI variants compared at each n (NMPCSettings fields)."""


def _build(model, u, settings: dict) -> tuple[NonlinearMPC, dict]:
    wall, cpu = time.perf_counter(), time.process_time()
    child = resource.getrusage(resource.RUSAGE_CHILDREN)
    ctl = NonlinearMPC(model, u, DT, NMPCSettings(horizon=HORIZON, **settings))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    spent = {
        "build_wall_s": time.perf_counter() - wall,
        "build_cpu_s": time.process_time() - cpu,
        "compiler_cpu_s": (after.ru_utime + after.ru_stime) - (child.ru_utime + child.ru_stime),
    }
    for name in ctl.engine.calls:
        ctl.engine.calls[name] = Timed(ctl.engine.calls[name])
    return ctl, spent


def at_length(n: int, samples: int, variants: dict = VARIANTS) -> dict:
    """The variants at chain length ``n`` over ``samples`` closed-loop samples."""
    pred = hanging_load(n, load_kg=LOAD_KG, flow_law="smooth", saturate=False)
    plant = hanging_load(n, load_kg=LOAD_KG)
    eq = solve_equilibrium(plant, {P_NAME: P_START})
    ctls, out = {}, {"n": n, "nx": plant.nx}
    for name, settings in variants.items():
        try:
            ctls[name], out[name] = _build(pred, eq.u, settings)
        except ParameterError as e:  # "banded" where the band does not pay
            out[name] = {"refused": str(e)}
    first = next(iter(ctls))
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    cpu = {k: [] for k in ctls}
    worst = 0.0
    for k in range(samples):
        y = sim.signals(ctls[first].outputs)
        r = {L_NAME: eq[L_NAME] - (3e-3 if k < samples // 2 else 2e-3) * (k > 2)}
        u = {}
        for name, c in ctls.items():
            tic = time.thread_time()
            u[name] = c.checked(sim.t, y, r)[P_NAME]
            cpu[name].append(time.thread_time() - tic)
        worst = max(worst, *(abs(u[first] - v) for v in u.values()))
        sim.step({P_NAME: u[first]}, DT)
    out["max_command_difference_Pa"] = worst
    for name, c in ctls.items():
        calls = c.engine.calls
        row = out[name]
        row["step_cpu_median_ms"] = float(np.median(cpu[name][1:]) * 1e3)
        for part in ("prepare", "feedback", "update"):
            row[f"{part}_cpu_median_ms"] = float(np.median(calls[part].cpu[1:]) * 1e3)
        row["fallbacks"] = c.stats.fallbacks
    for name in ctls:
        out[name]["ratio_to_dense"] = (
            out[name]["step_cpu_median_ms"] / out[first]["step_cpu_median_ms"]
        )
    return out


def study(ns=(3, 5, 8, 10), samples: int = 60, compiled_ns=(3, 10)) -> list[dict]:
    """:func:`at_length` for each n (the compiled variant only at ``compiled_ns``)."""
    rows = []
    for n in ns:
        keep = {k: v for k, v in VARIANTS.items() if k != "compiled" or n in compiled_ns}
        rows.append(at_length(n, samples, keep))
    return rows
