"""Accuracy of the co-simulation master against its communication step: Jacobi against
Gauss-Seidel, hold against extrapolation.

A one-way coupling of two native participants with the isometric model (1 APS): ``a``'s
regulator output ``regulator.p_out`` drives ``b``'s command ``regulator.p_cmd``, ``a``
driven by a command step (0.01 -> 0.08 MPa at 0.1 s, a communication point of every step
studied, so ``a`` itself is stepped exactly and only the coupling errs). The
error is ``max |T_b - T_b,ref| / max |T_b,ref|`` of ``b``'s thread tension
``myofibril.actin0.T`` at the communication points shared with the reference: the
Gauss-Seidel, extrapolated run at a 0.125 ms step (so the figures measure the coupling
error, not the error of one participant against another solver). The observed order is
the slope of log error against log step between the two smallest steps.

Usage::

    python benchmarks/cosim_accuracy.py --out docs/img/cosim_accuracy.png
"""

from __future__ import annotations

import argparse
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sarcomere.dynamics.assemblies import isometric  # noqa: E402
from sarcomere.fmu import Connection, NativeParticipant, cosimulate  # noqa: E402

STEPS = (0.02, 0.01, 0.005, 0.0025)
REFERENCE_STEP = 0.000125
STOP = 0.4
SIGNAL = "b.myofibril.actin0.T"


def command(t: float) -> float:
    """0.01 -> 0.08 MPa at 0.1 s [Pa]."""
    return 8e4 if t >= 0.1 else 1e4


def run(model, step: float, ordering: str, inputs: str) -> np.ndarray:
    parts = [NativeParticipant(model, "a"), NativeParticipant(model, "b")]
    r = cosimulate(
        parts,
        [Connection("a.regulator.p_out", "b.regulator.p_cmd")],
        stop_time=STOP,
        step=step,
        ordering=ordering,
        inputs=inputs,
        sources={"a.regulator.p_cmd": command},
        record=[SIGNAL],
    )
    return r[SIGNAL]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="the chart (PNG)")
    args = parser.parse_args()
    model = isometric(1)
    ref = run(model, REFERENCE_STEP, "gauss-seidel", "extrapolate")
    fig, ax = plt.subplots(figsize=(6, 4))
    for ordering in ("jacobi", "gauss-seidel"):
        for inputs in ("hold", "extrapolate"):
            errors = []
            for h in STEPS:
                every = round(h / REFERENCE_STEP)
                y = run(model, h, ordering, inputs)
                errors.append(np.max(np.abs(y - ref[::every])) / np.max(np.abs(ref)))
            order = math.log(errors[-2] / errors[-1]) / math.log(STEPS[-2] / STEPS[-1])
            label = f"{ordering}, {inputs}: order {order:.2f}"
            print(
                label,
                " ".join(f"{h * 1e3:g} ms {e:.2e}" for h, e in zip(STEPS, errors, strict=True)),
            )
            ax.loglog(np.array(STEPS) * 1e3, errors, "o-", label=label)
    ax.set_xlabel("communication step [ms]")
    ax.set_ylabel("max relative error of b's tension")
    ax.set_title("co-simulation: a's regulator output drives b (1 APS, isometric)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)


if __name__ == "__main__":
    main()
