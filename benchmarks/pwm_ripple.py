"""The averaged PWM valve's predicted error against the switched model's measured one
(``dynamics/fidelity/ripple.py``), and their CPU times side by side.

n = 3, 20 g, duty 0.2 to 0.8 x 20/50/100 Hz; each switched run starts at the averaged
equilibrium and runs 1.5 s, the deviation measured over its last 0.2 s. Prints, per
case and signal, predicted (with SAFETY) and measured largest |switched - averaged|, and
the CPU time (time.process_time, medians of 3 interleaved) of 1.5 s of a duty step
0.4 -> 0.6 at each level.

Run: .venv/bin/python benchmarks/pwm_ripple.py
"""

import statistics
import time

import numpy as np

from sarcomere.dynamics import hanging_load, simulate, solve_equilibrium
from sarcomere.dynamics.fidelity.ripple import SAFETY, predict
from sarcomere.dynamics.signals import Step

U = "valve.cmd"
SIGNALS = ["valve_hose.p_gauge", "myofibril.aps2.chamber.p_gauge", "myofibril.length"]


def ripple_table() -> None:
    worst = 0.0
    for d in (0.2, 0.3, 0.41, 0.5, 0.6, 0.7, 0.8):
        for f in (20, 50, 100):
            m = hanging_load(3, load_kg=0.02, supply="valve_pwm", valve={"frequency": f})
            pr = predict(m, d, SIGNALS)
            eq = solve_equilibrium(m, {U: d})
            r = simulate(m, 1.5, inputs={U: d}, x0=eq.x, output_interval=2e-4)
            last = r.index > 1.3
            for k in SIGNALS:
                meas = np.max(np.abs(r[k][last] - eq[k]))
                ratio = meas / (pr.error[k] / SAFETY)
                worst = max(worst, ratio)
                print(f"d={d} f={f:3d} {k:32s} pred {pr.error[k]:.3g} meas {meas:.3g} x{ratio:.2f}")
    print(f"largest measured / estimate (before SAFETY = {SAFETY:g}): {worst:.2f}")


def cpu_table() -> None:
    times = {"switched": [], "averaged": []}
    for _ in range(3):
        for level in times:
            m = hanging_load(3, load_kg=0.02, supply="valve_pwm", valve={"level": level})
            x0 = solve_equilibrium(m, {U: 0.4}).x
            simulate(m, 0.05, inputs={U: 0.4}, x0=x0)  # build the integrators
            tic = time.process_time()
            simulate(m, 1.5, inputs={U: Step(initial=0.4, final=0.6, time=0.5)}, x0=x0)
            times[level].append(time.process_time() - tic)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"CPU s: {med}, ratio {med['switched'] / med['averaged']:.1f}")


if __name__ == "__main__":
    ripple_table()
    cpu_table()
