"""Randomised study of ``fidelity = "auto"``: does the chosen level stay within its
tolerance off the packaged scenes, and what does auto cost against full?

Scenes are drawn with a fixed seed (:func:`draw`): n 1-60 units, loads 0-200 g, commands
of six kinds (step, ramp, staircase, sine, dither: a small sine around a mid pressure,
vent: a fall to 0 through a fast regulator), tolerances 1-10 %, the error measured on the
length (and on the top chamber's pressure in a third of the scenes). For each: the level
auto chose, its predicted error, its measured error (``max |y - y_ref| / span(y_ref)``
over the scene's signals, the reference ``full`` at rtol 1e-9, atol 1e-12), and the wall
time of the transient runner end to end (what ``summary.json`` reports) for auto and for
full at the scene's own settings (CVODES, rtol 1e-6), one BLAS thread, one run each
(full first; single runs on a shared machine: +/- 30 %). ``--part k/m`` measures every
m-th scene from the k-th (same draws), for m processes side by side. :func:`measure`
also runs a level without a model of its own (``linear``, ``equilibrium_path``) against
its own prediction (the tests' randomised check).

Usage::

    python benchmarks/auto_study.py --scenes 40 --seed 17 --out out/bench/auto_study.json
"""

from __future__ import annotations

import argparse
import gc
import json
import time
from pathlib import Path

import numpy as np

from sarcomere.scenarios import parse_scenario, transient
from sarcomere.scenarios.threads import limited_blas

KINDS = ("step", "ramp", "staircase", "sine", "dither", "vent")

TEMPLATE = """
[scenario]
name = "{name}"
kind = "transient"
[model]
name = "myofibril"
fidelity = "{fidelity}"
n = {n}
[model.options]
setup = "hanging"
load = "{load_g:.1f} g"
regulator_tau = "{tau_ms:.1f} ms"
[inputs.pressure]
{command}
[simulation]
stop_time = "{stop:.3f} s"
[solver]
method = "cvodes"
rtol = {rtol}
atol = {atol}
[outputs]
signals = {signals}
{tolerance}"""


def _kpa(x: float) -> str:
    return f'"{x:.2f} kPa"'


def draw(rng: np.random.Generator, index: int, n_max: int = 60) -> dict:
    """One random scene: its parameters and the command's TOML lines."""
    kind = KINDS[index % len(KINDS)] if index < len(KINDS) else str(rng.choice(KINDS))
    n = int(rng.integers(1, n_max + 1))
    load_g = float(rng.uniform(0.0, 200.0))
    tau_ms = 50.0
    hi = float(rng.uniform(20.0, 120.0))  # kPa
    start = float(rng.uniform(0.05, 0.3))
    if kind == "step":
        lo = float(rng.uniform(0.0, 0.5 * hi))
        cmd = f'type = "step"\ninitial = {_kpa(lo)}\nfinal = {_kpa(hi)}\ntime = "{start:.3f} s"'
        stop = start + float(rng.uniform(0.8, 2.0))
    elif kind == "ramp":
        dur = float(rng.uniform(0.3, 4.0))
        cmd = (
            f'type = "ramp"\nfinal = {_kpa(hi)}\nduration = "{dur:.3f} s"\nstart = "{start:.3f} s"'
        )
        stop = start + dur + float(rng.uniform(0.2, 1.0))
    elif kind == "staircase":
        k = int(rng.integers(3, 6))
        levels = rng.uniform(0.0, hi, k)
        dwell = float(rng.uniform(0.2, 0.8))
        cmd = (
            f'type = "staircase"\nlevels = [{", ".join(_kpa(v) for v in levels)}]\n'
            f'dwell = "{dwell:.3f} s"'
        )
        stop = k * dwell
    elif kind in ("sine", "dither"):
        amp = float(rng.uniform(2.0, 5.0) if kind == "dither" else rng.uniform(5.0, 0.5 * hi))
        offset = max(amp, 0.5 * hi)
        freq = float(rng.uniform(0.2, 5.0))
        cmd = (
            f'type = "sine"\noffset = {_kpa(offset)}\namplitude = {_kpa(amp)}\n'
            f'frequency = "{freq:.3f} Hz"'
        )
        stop = max(2.0 / freq, 1.0) if kind == "sine" else float(rng.uniform(3.0, 10.0))
    else:  # vent
        tau_ms = float(rng.uniform(5.0, 50.0))
        cmd = f'type = "step"\ninitial = {_kpa(hi)}\nfinal = "0 kPa"\ntime = "{start:.3f} s"'
        stop = start + float(rng.uniform(0.5, 1.5))
    signals = ["myofibril.length"]
    if rng.uniform() < 1 / 3:
        signals.append("myofibril.aps1.chamber.p_gauge")
    tol = float(rng.uniform(1.0, 10.0))
    return {
        "name": f"s{index:02d}-{kind}-n{n}",
        "kind": kind,
        "n": n,
        "load_g": load_g,
        "tau_ms": tau_ms,
        "command": cmd,
        "stop": stop,
        "signals": signals,
        "tolerance_percent": tol,
    }


def scene_text(scene: dict, fidelity: str, tight: bool = False) -> str:
    """The scene as a scenario file at ``fidelity`` (the tolerance only for auto)."""
    tolerance = f'tolerance = "{scene["tolerance_percent"]:.2f} %"' if fidelity == "auto" else ""
    return TEMPLATE.format(
        fidelity=fidelity,
        rtol=1e-9 if tight else 1e-6,
        atol=1e-12 if tight else 1e-9,
        signals=json.dumps(scene["signals"]),
        tolerance=tolerance,
        **{k: scene[k] for k in ("name", "n", "load_g", "tau_ms", "command", "stop")},
    )


def run(text: str):
    """The transient runner on a scenario text: (RunOutput, wall time [s])."""
    sc = parse_scenario(text, "scene.toml")
    gc.collect()
    tic = time.perf_counter()
    out = transient.run_transient(sc, Path("."))
    return out, time.perf_counter() - tic


def measure(scene: dict, timing: bool = True, level: str = "auto") -> dict:
    """The level run (auto's choice, or ``level``), its predicted and measured error, and
    (``timing``) its and full's end-to-end wall times."""
    if timing:
        _, t_full = run(scene_text(scene, "full"))
    auto, t_auto = run(scene_text(scene, level))
    ref, _ = run(scene_text(scene, "full", tight=True))
    a, r = auto.results["main"], ref.results["main"]
    err = max(float(np.max(np.abs(a[s] - r[s])) / np.ptp(r[s])) for s in scene["signals"])
    row = {
        **scene,
        "chosen": auto.fidelity,
        "predicted": auto.metrics.get("fidelity_predicted_error", 0.0),
        "measured": err,
        "tolerance": scene["tolerance_percent"] / 100,
    }
    if timing:
        row.update(auto_s=t_auto, full_s=t_full, cost_ratio=t_auto / t_full)
    return row


def study(
    count: int, seed: int, n_max: int = 60, timing: bool = True, part: tuple = (0, 1)
) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(count):
        scene = draw(rng, i, n_max)
        if i % part[1] != part[0]:
            continue
        row = measure(scene, timing)
        rows.append(row)
        cost = f"auto/full {row['cost_ratio']:.2f}" if timing else ""
        print(
            f"{row['name']:24s} tol {row['tolerance'] * 100:5.2f} % {row['chosen']:17s} "
            f"pred {row['predicted'] * 100:7.3f} % meas {row['measured'] * 100:7.3f} % "
            f"{'OK ' if row['measured'] <= row['tolerance'] else 'BAD'} {cost}",
            flush=True,
        )
    return rows


def table(rows: list[dict]) -> str:
    """The markdown table of docs/numerics.md."""
    lines = [
        "| scene | load | tolerance | chosen | predicted | measured | auto / full |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        pred = "0" if r["chosen"] == "full" else f"{r['predicted'] * 100:.3g} %"
        cost = f"{r['auto_s'] * 1e3:.0f} / {r['full_s'] * 1e3:.0f} ms (x{r['cost_ratio']:.2f})"
        lines.append(
            f"| {r['name']} | {r['load_g']:.0f} g | {r['tolerance'] * 100:.2f} % | {r['chosen']} "
            f"| {pred} | {r['measured'] * 100:.3g} % | {cost} |"
        )
    return "\n".join(lines)


def _order(row: dict) -> str:
    return row["name"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=17)
    parser.add_argument("--n-max", type=int, default=60)
    parser.add_argument("--out", type=Path, default=Path("out/bench/auto_study.json"))
    parser.add_argument("--part", default="0/1", help="k/m: every m-th scene from the k-th")
    parser.add_argument("--table", nargs="+", type=Path, help="only print the table of these")
    args = parser.parse_args()
    if args.table:
        rows = sorted((r for f in args.table for r in json.loads(f.read_text())), key=_order)
        print(table(rows))
        return
    part = tuple(int(v) for v in args.part.split("/"))
    with limited_blas():
        rows = study(args.scenes, args.seed, args.n_max, part=part)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    print(table(rows))
    bad = [r["name"] for r in rows if r["measured"] > r["tolerance"]]
    print(f"{len(rows)} scenes, {len(bad)} beyond their tolerance {bad}")


if __name__ == "__main__":
    main()
