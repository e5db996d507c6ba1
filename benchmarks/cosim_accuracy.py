"""Accuracy and stability of the co-simulation master against its communication step:
Jacobi against Gauss-Seidel, hold against extrapolation.

**One-way**: two native participants with the isometric model (1 APS): ``a``'s regulator
output ``regulator.p_out`` drives ``b``'s command ``regulator.p_cmd``, ``a`` driven by a
command step (0.01 -> 0.08 MPa at 0.1 s, a communication point of every step studied, so
``a`` itself is stepped exactly and only the coupling errs). The error is
``max |T_b - T_b,ref| / max |T_b,ref|`` of ``b``'s thread tension ``myofibril.actin0.T``
at the communication points shared with the reference: the Gauss-Seidel, extrapolated run
at a 0.125 ms step.

**Two-way** (``benchmarks/studies/cosim_coupling.py``, the set-ups of
:mod:`sarcomere.dynamics.assemblies`): the muscle (1 APS, a 20 g hook) and a 50 g load on
a spring, split into two native participants (the hook's position drives the spring, its
tension pulls the hook), command 0.02 -> 0.08 MPa at 20 ms, 0.2 s. The error is
``max |s - s_ref| / ptp(s_ref)`` of the load's position against the same system as one
model (CVODES, rtol 1e-10), at the communication points. Then the spring's stiffness is
swept: a run that fails (a participant leaves the physical domain) or whose error grows
(``diverges``) is unstable, and the linear analysis (``amplification``) gives the
boundary. With hold, the runs are repeated with the load as its exported FMU (FMI 2.0,
built once, about 3 s of gcc).

The observed order is the slope of log error against log step between the two smallest
steps. Writes ``cosim_accuracy.png`` (one-way), ``cosim_two_way.png``,
``cosim_stability.png`` and ``cosim_accuracy.json`` into ``--out-dir``.

Usage::

    python benchmarks/cosim_accuracy.py --out-dir docs/img
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from studies import cosim_coupling as study  # noqa: E402

from sarcomere.dynamics.assemblies import isometric  # noqa: E402
from sarcomere.dynamics.simulation.settings import SolverSettings  # noqa: E402
from sarcomere.fmu import (  # noqa: E402
    Connection,
    CosimError,
    NativeParticipant,
    cosimulate,
    export_fmu,
    open_fmu,
)

ORDERINGS = ("jacobi", "gauss-seidel")
COMBOS = [(o, i) for o in ORDERINGS for i in ("hold", "extrapolate")]

STEPS = (0.02, 0.01, 0.005, 0.0025)
REFERENCE_STEP = 0.000125
STOP = 0.4
SIGNAL = "b.myofibril.actin0.T"

TWO_WAY_C = 200.0
"""The spring of the two-way accuracy study [N/m] (relative mode 19 Hz)."""
TWO_WAY_STEPS = (0.004, 0.002, 0.001, 0.0005, 0.00025)
TWO_WAY_STOP = 0.2
COMMAND = (2e4, 8e4, 0.02)
"""0.02 -> 0.08 MPa at 20 ms (a communication point of every step) [Pa, Pa, s]."""
PARTICIPANTS = SolverSettings(rtol=1e-9, atol=1e-12)
"""The participants' CVODES: far below the coupling errors measured."""
SWEEP_C = (1e3, 3e3, 1e4, 3e4, 1e5)
SWEEP_STEPS = (0.00025, 0.0005, 0.001, 0.002)
BOUNDARY_C = tuple(np.logspace(2.5, 5, 11))


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


def order(steps, errors) -> float:
    """Slope of log error against log step between the two smallest steps."""
    return math.log(errors[-2] / errors[-1]) / math.log(steps[-2] / steps[-1])


def one_way() -> dict:
    model = isometric(1)
    ref = run(model, REFERENCE_STEP, "gauss-seidel", "extrapolate")
    out = {}
    for ordering, inputs in COMBOS:
        errors = []
        for h in STEPS:
            y = run(model, h, ordering, inputs)
            errors.append(float(np.max(np.abs(y - ref[:: round(h / REFERENCE_STEP)]))))
        errors = [e / float(np.max(np.abs(ref))) for e in errors]
        out[f"{ordering}, {inputs}"] = {"errors": errors, "order": order(STEPS, errors)}
    return out


def _grid(step: float) -> np.ndarray:
    return np.linspace(0.0, TWO_WAY_STOP, round(TWO_WAY_STOP / step) + 1)


def two_way(load_fmu: Path) -> dict:
    """Every ordering and input law with native participants; with hold, also with the
    load as its exported FMU (labels ending in ", load FMU")."""
    finest = TWO_WAY_STEPS[-1]
    ref = study.monolithic_run(TWO_WAY_C, COMMAND, TWO_WAY_STOP, _grid(finest))["mass.s"]
    out = {}
    cases = [(o, i, False) for o, i in COMBOS] + [(o, "hold", True) for o in ORDERINGS]
    for ordering, inputs, fmu in cases:
        errors = []
        for h in TWO_WAY_STEPS:
            with open_fmu(load_fmu) as opened:
                r = study.cosimulate_split(
                    TWO_WAY_C,
                    h,
                    ordering,
                    inputs,
                    COMMAND,
                    TWO_WAY_STOP,
                    settings=PARTICIPANTS,
                    load_fmu=opened if fmu else None,
                )
            e = np.abs(r["load.mass.s"] - ref[:: round(h / finest)])
            errors.append(float(np.max(e) / np.ptp(ref)))
        ratios = [errors[k] / errors[k + 1] for k in range(len(errors) - 1)]
        out[f"{ordering}, {inputs}{', load FMU' if fmu else ''}"] = {
            "errors": errors,
            "order": order(TWO_WAY_STEPS, errors),
            "orders": [math.log2(q) for q in ratios],
        }
    return out


def stability(load_fmu: Path) -> dict:
    """Nonlinear runs over the stiffness and step grid (with hold, also with the load as
    its FMU: ``"fmu": true``), and the linear boundary."""
    finest = min(SWEEP_STEPS)
    runs = []
    cases = [(o, i, False) for o, i in COMBOS] + [(o, "hold", True) for o in ORDERINGS]
    for c in SWEEP_C:
        ref = study.monolithic_run(c, COMMAND, TWO_WAY_STOP, _grid(finest))["sensor.f"]
        for ordering, inputs, fmu in cases:
            for h in SWEEP_STEPS:
                row = {"c": c, "h": h, "ordering": ordering, "inputs": inputs, "fmu": fmu}
                row["radius"] = study.amplification(c, h, ordering, inputs, COMMAND[1])
                try:
                    with open_fmu(load_fmu) as opened:
                        r = study.cosimulate_split(
                            c,
                            h,
                            ordering,
                            inputs,
                            COMMAND,
                            TWO_WAY_STOP,
                            load_fmu=opened if fmu else None,
                        )
                except CosimError as err:
                    row.update(stable=False, why=f"failed at t = {err.time:.4g} s", error=None)
                else:
                    e = np.abs(r["load.sensor.f"] - ref[:: round(h / finest)])
                    grows = study.diverges(e)
                    row.update(stable=not grows, why="error grows" if grows else "")
                    row["error"] = float(np.max(e) / study.start_force())
                runs.append(row)
    boundary = {}
    for ordering, inputs in COMBOS:
        rows = []
        for c in BOUNDARY_C:
            h = study.critical_step(c, ordering, inputs, COMMAND[1], (1e-7, 2e-2))
            d = study.relative_mode_damping(c, COMMAND[1])
            rows.append(
                {
                    "c": float(c),
                    "h_critical": h,
                    "h_omega": h * study.coupled_frequency(c),
                    "h_c_over_d": h * c / d,
                    "damping": d,
                }
            )
        boundary[f"{ordering}, {inputs}"] = rows
    return {"runs": runs, "boundary": boundary}


def _chart(path: Path, steps, results: dict, ylabel: str, title: str) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, r in results.items():
        ax.loglog(
            np.array(steps) * 1e3, r["errors"], "o-", label=f"{label}: order {r['order']:.2f}"
        )
    ax.set_xticks(np.array(steps) * 1e3, [f"{h * 1e3:g}" for h in steps])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("communication step [ms]")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _stability_chart(path: Path, stab: dict) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    styles = {"jacobi": "C0", "gauss-seidel": "C1"}
    for ax, law in zip(axes, ("hold", "extrapolate"), strict=True):
        for ordering, colour in styles.items():
            rows = stab["boundary"][f"{ordering}, {law}"]
            ax.loglog(
                [r["c"] for r in rows],
                [r["h_critical"] * 1e3 for r in rows],
                "-",
                color=colour,
                label=f"{ordering}: linear boundary",
            )
            for r in stab["runs"]:
                if (r["ordering"], r["inputs"], r["fmu"]) == (ordering, law, False):
                    shift = 0.93 if ordering == "jacobi" else 1.07  # side by side
                    ax.plot(
                        r["c"] * shift,
                        r["h"] * 1e3,
                        "o" if r["stable"] else "x",
                        color=colour,
                        mfc="none",
                    )
        ax.set_xlabel("coupling spring c [N/m]")
        ax.set_title(f"{law}: o stable, x unstable (nonlinear runs)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("communication step [ms]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out-dir", required=True, type=Path, help="charts and JSON")
    args = parser.parse_args()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    results = {"one_way": {"steps": STEPS, "results": one_way()}}
    with tempfile.TemporaryDirectory() as folder:  # the load participant's FMU (FMI 2.0)
        load_fmu = export_fmu(study.load_participant_model(TWO_WAY_C), Path(folder) / "load.fmu")
        results["two_way"] = {
            "c": TWO_WAY_C,
            "steps": TWO_WAY_STEPS,
            "results": two_way(load_fmu),
        }
        results["stability"] = stability(load_fmu)
    results["run_time_s"] = time.perf_counter() - started
    for part in ("one_way", "two_way"):
        for label, r in results[part]["results"].items():
            errs = " ".join(f"{e:.2e}" for e in r["errors"])
            print(f"{part} {label}: {errs}  order {r['order']:.2f}")
    for label, rows in results["stability"]["boundary"].items():
        print(label, " ".join(f"{r['h_c_over_d']:.2f}" for r in rows))
    runs = [r for r in results["stability"]["runs"] if not r["fmu"]]
    agree = sum(r["stable"] == (r["radius"] <= 1) for r in runs)
    with_fmu = {
        (r["c"], r["h"], r["ordering"]): r["stable"]
        for r in results["stability"]["runs"]
        if r["fmu"]
    }
    alike = sum(
        r["stable"] == with_fmu[(r["c"], r["h"], r["ordering"])]
        for r in runs
        if r["inputs"] == "hold"
    )
    results["stability"]["fmu_alike_native"] = [alike, len(with_fmu)]
    print(f"the load as an FMU is classified as the native load in {alike} of {len(with_fmu)}")
    results["stability"]["agree_with_linear"] = agree
    print(f"{sum(not r['stable'] for r in runs)} of {len(runs)} runs unstable; ", end="")
    print(f"{agree} agree with the linear analysis (radius <= 1: stable)")
    for r in runs:
        if r["stable"] != (r["radius"] <= 1):
            print("  disagree:", r)
    print(f"run time {results['run_time_s']:.0f} s")
    (args.out_dir / "cosim_accuracy.json").write_text(json.dumps(results, indent=1))
    _chart(
        args.out_dir / "cosim_accuracy.png",
        STEPS,
        results["one_way"]["results"],
        "max relative error of b's tension",
        "one-way: a's regulator output drives b (1 APS, isometric)",
    )
    _chart(
        args.out_dir / "cosim_two_way.png",
        TWO_WAY_STEPS,
        results["two_way"]["results"],
        "max error of the load position / its range",
        f"two-way: muscle and load on a {TWO_WAY_C:g} N/m spring, vs monolithic",
    )
    _stability_chart(args.out_dir / "cosim_stability.png", results["stability"])


if __name__ == "__main__":
    main()
