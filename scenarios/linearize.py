"""``sarcomere linearize SCENARIO --out DIR``: the exact linearisation of a scene's model.

The operating point is the equilibrium at the regulator command ``--pressure`` (with its
unit, ``'50 kPa'``; default: a closed-loop scene's ``[control] operating_pressure``, a
transient's pressure at its start time); the outputs are ``--output`` (repeatable; default
the closed-loop scene's tracked signal, else the length of a hanging chain or the force of
an isometric one). A ``fidelity = "auto"`` scene is linearised at ``full``.
Written, all or nothing (:func:`~.outdir.staged`):

* ``linearization.json``: the operating point, the names (model names and python-control
  labels), ``A, B, C, D`` and every pole with its physical mode
  (:func:`~sarcomere.controllers.linearize.classify_poles`);
* ``matrices.npz``: ``A, B, C, D`` and the name arrays;
* ``bode.png``: gain and phase of each output from the regulator command;
* ``summary.json``: the slowest pole, the lowest resonance and the static gains.
"""

from __future__ import annotations

import argparse
import json
import math
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ScenarioError

from .catalog import version
from .outdir import check_out_dir, staged

P_CMD = "regulator.p_cmd"
ROBOT_OUTPUTS = {"joint": ["joint.theta", "stiffness.K"]}
"""Default outputs of a robot set-up (``Binding.setup``): the joint's angle and stiffness."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``SCENARIO --out DIR [--pressure P] [--output NAME ...]``."""
    parser.add_argument(
        "scenario",
        help="scenario file or packaged name (kind transient "
        "or closed_loop; any myofibril scene with --pressure)",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--pressure", help="regulator command at the operating point ('50 kPa')")
    parser.add_argument(
        "--output", action="append", metavar="NAME", help="output signal (repeatable)"
    )


def _pressure(sc, given: str | None) -> float:
    from sarcomere.dynamics.units import to_si

    if given is not None:  # a unit is needed, as in scene files: 100 (Pa? kPa?) is refused
        return to_si(given, "Pa", "--pressure", bare_ok=False)
    if sc.kind == "closed_loop" and "operating_pressure" in sc.control:
        return to_si(sc.control["operating_pressure"], "Pa", "control.operating_pressure")
    if sc.kind == "transient" and "pressure" in sc.inputs:
        start = sc.simulation.start_time if sc.simulation else 0.0
        return float(sc.inputs["pressure"](start))
    raise ScenarioError(
        sc.file, "--pressure", f"kind '{sc.kind}' names no operating pressure: give one ('50 kPa')"
    )


def linearize_scenario(source: str | Path, out_dir: Path, pressure=None, outputs=None) -> dict:
    """Linearise the scene's model and write the files into ``out_dir`` (which exists);
    returns the summary metrics."""
    # imported here, not at the top: ``sarcomere linearize --help`` stays light
    from sarcomere.controllers.linearize import classify_poles, linearize, operating_point
    from sarcomere.dynamics.modeling.labels import to_label

    from .binding import bind, command_range, distinct, fidelity_level, scene_inputs
    from .loader import load_scenario
    from .spec import did_you_mean

    sc = load_scenario(source)
    if sc.kind == "static":
        raise ScenarioError(
            sc.file, "scenario.kind", "'static' is the paper's closed-form model: no dynamics"
        )
    b = bind(sc)
    fid = fidelity_level(sc, allow_auto=True)
    fid = "full" if fid == "auto" else fid  # auto picks a run's level; this is exact anyway
    model = b.build(fid)
    if sc.kind == "transient":
        scene_inputs(sc, model)  # the scene's inputs are checked as a run would
    commands = getattr(b, "inputs", [P_CMD])  # a robot set-up: a command per chain
    if pressure is None and sc.kind == "transient" and "pressure" not in sc.inputs:
        given = scene_inputs(sc, model)  # each command at the scene's start
        start = sc.simulation.start_time if sc.simulation else 0.0
        point = {n: float(given[n](start)) if n in given else 0.0 for n in commands}
    else:
        point = dict.fromkeys(commands, _pressure(sc, pressure))
    for name, p in point.items():
        low, high = command_range(model, b.overrides, name)
        if pressure is not None and not low <= p <= high:
            raise ScenarioError(
                sc.file,
                "--pressure",
                f"{distinct(p / 1e6, (low / 1e6, high / 1e6))} MPa is outside the regulator's "
                f"range [{low / 1e6:g}, {high / 1e6:g}] MPa",
            )
    default = sc.control.get("output") or (
        "sensor.f" if b.setup.endswith("isometric") else "myofibril.length"
    )
    outs = list(outputs or (ROBOT_OUTPUTS.get(b.setup) or [default]))
    for name in outs:
        if name not in model.signal_names:
            hint = did_you_mean(name, model.signal_names)
            raise ScenarioError(sc.file, "--output", f"'{name}' is not a signal of the model{hint}")
    op = operating_point(model, point, b.overrides)
    sys = linearize(model, op, outs, inputs=commands)
    poles = classify_poles(model, sys)
    A, B, C, D = sys.A, sys.B, sys.C, sys.D
    gains = np.asarray(sys.dcgain()).reshape(len(outs), len(commands))
    static = (
        dict(zip(outs, gains[:, 0].tolist(), strict=True))
        if len(commands) == 1
        else {
            f"{o}__{i}": float(gains[j, k])
            for j, o in enumerate(outs)
            for k, i in enumerate(commands)
        }
    )
    record = {
        "scenario": sc.name,
        "fidelity": fid,
        "operating_point": {**{f"{n}_Pa": v for n, v in point.items()}, **{n: op[n] for n in outs}},
        "states": model.state_names,
        "inputs": commands,
        "outputs": outs,
        "labels": {n: to_label(n) for n in [*model.state_names, *commands, *outs]},
        "A": A.tolist(),
        "B": B.tolist(),
        "C": C.tolist(),
        "D": D.tolist(),
        "poles": poles,
        "static_gain": static,
    }
    (out_dir / "linearization.json").write_text(json.dumps(record, indent=1))
    np.savez(
        out_dir / "matrices.npz",
        A=A,
        B=B,
        C=C,
        D=D,
        states=np.array(model.state_names),
        inputs=np.array(commands),
        outputs=np.array(outs),
    )
    _bode(sys, outs, commands, out_dir / "bode.png", sc.name)
    resonant = [r for r in poles if r["imag_1_s"] > 0]
    metrics = {
        "states": float(model.nx),
        "slowest_pole_1_s": poles[0]["real_1_s"],
        "fastest_pole_1_s": min(r["real_1_s"] for r in poles),
        "lowest_resonance_Hz": resonant[0]["frequency_Hz"] if resonant else 0.0,
        **{f"static_gain_{n}": g for n, g in record["static_gain"].items()},
    }
    summary = {
        "scenario": f"linearize {sc.name}",
        "fidelity": fid,
        "solver": "exact CasADi Jacobians at the equilibrium (damped Newton)",
        "metrics": metrics,
        "modes": [_mode_line(r) for r in poles],
        "provenance": {
            "sarcomere_version": version(),
            "utc": datetime.now(UTC).isoformat(timespec="seconds"),
        },
        "files": ["linearization.json", "matrices.npz", "bode.png"],
    }
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _mode_line(r: dict) -> str:
    """``"load (load.s): -21.8 +/- 36.1j 1/s"``."""
    imag = f" +/- {r['imag_1_s']:.4g}j" if r["imag_1_s"] else ""
    return f"{r['mode']} ({r['dominant_state']}): {r['real_1_s']:.4g}{imag} 1/s"


def _bode(sys, outs: list[str], ins: list[str], path: Path, title: str) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # lazy: CLI start-up
    from matplotlib.figure import Figure

    w = np.logspace(math.log10(2 * math.pi * 0.05), math.log10(2 * math.pi * 2000), 400)
    import control as ct

    resp = ct.frequency_response(sys, w)
    pairs = [(o, i) for o in outs for i in ins]
    mag = np.abs(resp.complex).reshape(len(pairs), -1)
    phase = np.unwrap(np.angle(resp.complex).reshape(len(pairs), -1), axis=1)
    fig = Figure(figsize=(6.4, 6.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax_m, ax_p = fig.add_subplot(211), fig.add_subplot(212, sharex=None)
    f = w / (2 * math.pi)
    for k, (name, cmd) in enumerate(pairs):
        ax_m.loglog(f, mag[k], label=f"{name} / {cmd}")
        ax_p.semilogx(f, np.degrees(phase[k]), label=name if len(ins) == 1 else f"{name} / {cmd}")
    ax_m.set_ylabel("gain [SI / Pa]")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [Hz]")
    ax_m.set_title(f"{title}: linearisation from {', '.join(ins)}")
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    ax_m.legend(fontsize="small")
    fig.savefig(path, dpi=120)


def handler(args: argparse.Namespace) -> int:
    """Write the files; print the operating point and the poles by mode."""
    folder = check_out_dir(args.out, "--out")
    with staged(folder) as tmp:
        summary = linearize_scenario(args.scenario, tmp, args.pressure, args.output)
    print(f"{summary['scenario']}: wrote {folder}: summary.json, {', '.join(summary['files'])}")
    for line in summary["modes"]:
        print(f"  {line}")
    return 0
