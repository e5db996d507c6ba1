"""A closed loop on the stepping Simulator against ``simulate`` of the same input.

n = 3 APS, 50 g, from the 0 MPa equilibrium; 1000 steps of 10 ms with CVODES (rtol 1e-6).
Side by side in one run, every variant timed as the median of ``--repeats`` warm runs
(the first, cold run builds the integrator and is reported apart):

* ``loop_staircase``: ``Simulator.step`` with a new constant command each step, drawn
  beforehand uniformly in [0, 0.2] MPa (seed 0);
* ``loop_p_law``: the same loop closed by a high-gain proportional law on the chain length
  (``sim.signal("myofibril.length")`` read after each step, command clipped to
  [0, 0.2] MPa): what a controller in the loop costs;
* ``simulate_staircase``: ``simulate`` given the same levels open-loop as a
  ``Staircase`` (output every 10 ms, one signal);
* ``integrator_only``: the method's own CasADi integrator (the one the simulator uses)
  called directly 1000 times with the loop's states and commands: the floor;
* ``loop_trivial``: the loop on a 1-state lag (``tau x' = u - x``), where the integrator
  costs almost nothing: the Python overhead per step.

Usage::

    python benchmarks/closed_loop.py --out out/bench/closed_loop.json [--repeats 7]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from sarcomere.dynamics import (
    Simulator,
    SolverSettings,
    Staircase,
    hanging_load,
    simulate,
    solve_equilibrium,
)
from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.simulation.settings import HELD
from sarcomere.dynamics.simulation.sundials import integrator

N_STEPS, H = 1000, 0.01
P_MAX = 2e5
SETTINGS = SolverSettings("cvodes", rtol=1e-6, atol=1e-9)
CMD = "regulator.p_cmd"


class _Lag(Component):
    def build(self, b) -> None:
        u = b.input("u", "1", "command")
        x = b.state("x", 0.0, "1", "lagged command")
        b.der(x, (u - x) / 0.1)


def _trivial_model():
    sys = System("lag")
    sys.add(_Lag("lag"))
    return sys.flatten()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/closed_loop.json"))
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    model = hanging_load(n=3, load_kg=0.05)
    rest = solve_equilibrium(model, {CMD: 0.0})
    levels = np.random.default_rng(0).uniform(0.0, P_MAX, N_STEPS)
    stair = Staircase(levels=tuple(levels.tolist()), dwell=H, unit="Pa")
    sim = Simulator(model, SETTINGS)
    L_ref = rest.signals["myofibril.length"] - 2e-3  # contract by 2 mm
    trivial = _trivial_model()
    tsim = Simulator(trivial, SETTINGS)
    record: dict[str, list] = {}

    def loop_staircase():
        sim.reset(x0=rest.x)
        for level in levels:
            sim.step([level], H)
        record["x_loop"] = sim.x

    def loop_p_law():
        sim.reset(x0=rest.x)
        u = 0.0
        for _ in range(N_STEPS):
            sim.step([u], H)
            u = min(max(2e8 * (sim.signal("myofibril.length") - L_ref), 0.0), P_MAX)

    def simulate_staircase():
        res = simulate(
            model,
            N_STEPS * H,
            {CMD: stair},
            x0=rest.x,
            settings=SETTINGS,
            output_interval=H,
            signals=["myofibril.length"],
        )
        record["x_simulate"] = np.array(res.meta["x_final"])

    F = integrator(model, SETTINGS, HELD, (1.0,))
    p = np.append(model.parameters(), (0.0, H))
    states = []

    def integrator_only():
        x = rest.x
        for level in levels:
            x = F(x0=x, z0=[], p=p, u=level)["xf"]
        states.append(np.array(x).ravel())

    def loop_trivial():
        tsim.reset()
        for level in levels / P_MAX:
            tsim.step([level], H)

    variants = {
        "loop_staircase": loop_staircase,
        "loop_p_law": loop_p_law,
        "simulate_staircase": simulate_staircase,
        "integrator_only": integrator_only,
        "loop_trivial": loop_trivial,
    }
    cold, walls = {}, {k: [] for k in variants}
    for name, fn in variants.items():
        tic = time.perf_counter()
        fn()
        cold[name] = time.perf_counter() - tic
    for _ in range(args.repeats):  # interleaved: every repeat runs every variant
        for name, fn in variants.items():
            tic = time.perf_counter()
            fn()
            walls[name].append(time.perf_counter() - tic)
    med = {k: statistics.median(v) for k, v in walls.items()}
    sim.reset(x0=rest.x)
    for level in levels:
        sim.step([level], H)
    result = {
        "scenario": f"hanging_load(n=3, 0.05 kg), {N_STEPS} steps of {H * 1e3:g} ms, "
        f"commands uniform in [0, {P_MAX / 1e6:g}] MPa, CVODES rtol {SETTINGS.rtol:g}",
        "repeats": args.repeats,
        "median_s": med,
        "cold_s": cold,
        "ratio_loop_to_simulate": med["loop_staircase"] / med["simulate_staircase"],
        "ratio_p_law_loop_to_simulate": med["loop_p_law"] / med["simulate_staircase"],
        "per_step_us": {k: v / N_STEPS * 1e6 for k, v in med.items()},
        "python_overhead_per_step_us": (med["loop_staircase"] - med["integrator_only"])
        / N_STEPS
        * 1e6,
        "loop_vs_simulate_final_state_max_rel_diff": float(
            np.max(np.abs(record["x_loop"] - record["x_simulate"]) / np.abs(record["x_simulate"]))
        ),
        "cvodes_steps_per_10ms_step": sim.stats["n_steps"] / N_STEPS,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
