"""CPU time of the antagonistic joint's simulation against real time (issue 26).

Open loop (no controller: the joint-control scene is not built), the joint's packaged
scenes' models: ``joint-cocontraction`` (symmetric level, 2 s) and the ``joint-stiffness``
model (full level, n = 3 per muscle) on a 2 s command step, each simulated with CVODES and
with the compiled Radau IIA at the scene's tolerances, from the start equilibrium. CPU
time (``time.process_time``) of ``binding.run`` (equilibrium + simulation), the median of
``--repeats`` warm runs after one cold run (model build and compilation excluded).

Usage::

    python benchmarks/joint_speed.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from sarcomere.dynamics.robots import antagonistic_joint
from sarcomere.dynamics.signals import Step
from sarcomere.dynamics.simulation.settings import SolverSettings
from sarcomere.scenarios import binding

FLEX, EXT = "flexor_regulator.p_cmd", "extensor_regulator.p_cmd"


def measure(fidelity: str, method: str, repeats: int) -> tuple[float, float]:
    """Median CPU time [s] of a 2 s run and its ratio to real time."""
    model = antagonistic_joint(3, fidelity=fidelity)
    inputs = {
        FLEX: Step(initial=0.05e6, final=0.2e6, time=0.5, unit="Pa"),
        EXT: Step(initial=0.05e6, final=0.1e6, time=1.0, unit="Pa"),
    }
    grid = np.linspace(0.0, 2.0, 401)
    settings = SolverSettings(method=method, rtol=1e-6, atol=1e-9)
    signals = ["joint.theta", "stiffness.K", "flexor_tendon.T", "extensor_tendon.T"]
    binding.run(model, inputs, {}, grid, settings, signals)  # cold: builds, compiles
    times = []
    for _ in range(repeats):
        tic = time.process_time()
        binding.run(model, inputs, {}, grid, settings, signals)
        times.append(time.process_time() - tic)
    cpu = statistics.median(times)
    return cpu, 2.0 / cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    for fidelity in ("symmetric", "full"):
        for method in ("cvodes", "radau"):
            cpu, ratio = measure(fidelity, method, args.repeats)
            cpu_ms = f"{cpu * 1e3:8.1f} ms"
            print(f"{fidelity:10s} {method:7s} CPU {cpu_ms} per 2 s: {ratio:6.1f}x real time")


if __name__ == "__main__":
    main()
