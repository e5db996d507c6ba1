"""The MPCs' default weights chosen by a stated criterion: a coarse grid on the control
scenes.

**What runs.** The packaged scenes ``control-length`` (12.5 s: -1.5 mm step, 3/1/0.2 Hz
sines, +50 g at 6.25 s) and ``control-tension`` (2.5 s: a -6 mm step, every thread
>= 0.2 N), unchanged but for their controllers: each scene is run once with ``lqi`` (the
reference) and one NMPC and one LMPC per grid point, all on the exact states (the
scenes' ``nmpc`` and ``lmpc`` rows; the estimator is not tuned here), with the scenes' own
limits, noise, seed and preview. Stage 1: every ``weight_y`` of :data:`WEIGHTS_Y` x
``weight_du`` of :data:`WEIGHTS_DU` at the default horizon. Stage 2: the horizons of
:data:`HORIZONS` at the weights stage 1 chose (reported; the default horizon changes only
if a longer one is admissible and scores lower).

**Criterion** (:func:`choose`), per controller: a point is *admissible* if on
``control-length`` its step overshoots by at most :data:`OVERSHOOT_MAX_PCT`, on
``control-tension`` the plant's threads break the bound by at most
:data:`VIOLATION_MAX_MN`, and no sample of either fell back. Its *score* is the mean over
the two scenes of its RMSE divided by LQI's in the same run. The admissible point with the
lowest score wins (scores equal to :data:`SCORE_DIGITS` decimals tie; a tie goes to the point
nearest the current defaults, in decades of both weights: only the ratio
``weight_y / weight_du`` matters where no other cost term does); if none is admissible,
the point with
the smallest excess over the two bounds (each divided by its bound), then the lowest score.
Stage 2 keeps the default horizon unless an admissible other horizon scores lower by more
than :data:`HORIZON_GAIN` (5 %: a step's cost grows with the horizon).

Usage::

    python benchmarks/mpc_tuning.py --out out/bench/mpc_tuning \
        [--weights-y 1e6 ...] [--weights-du 1e-9 ...] [--horizons 10 20 40]

(a smaller grid for a cheaper run; the grid run is recorded in the JSON)

writes ``mpc_tuning.json`` (every point's metrics, the LQI rows, the choice) and prints
the tables.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from sarcomere.scenarios.control import run_closed_loop_scene
from sarcomere.scenarios.loader import parse_scenario, resolve_scenario

SCENES = ("control-length", "control-tension")
CONTROLLERS = ("nmpc", "lmpc")
WEIGHTS_Y = (1e5, 1e6, 1e7)
"""Tracking weights [1/m^2] of the grid."""
WEIGHTS_DU = (1e-10, 3e-10, 1e-9, 3e-9, 1e-8, 3e-8, 1e-7, 3e-7)
"""Move weights [1/Pa^2] of the grid."""
HORIZONS = (10, 20, 40)
"""Horizons [samples] of stage 2 (20 is the default)."""
SCORE_DIGITS = 3
"""Decimals to which two scores are compared: closer is run-to-run noise."""
HORIZON_GAIN = 0.05
"""Stage 2 moves the horizon from the default only for a score lower by more than this
fraction: the cost of a step grows about in proportion to the horizon."""
OVERSHOOT_MAX_PCT = 10.0
"""Largest admissible overshoot of control-length's step [%] (issue 18's target)."""
VIOLATION_MAX_MN = 1.0
"""Largest admissible tension-bound violation on control-tension [mN] (issue 18's)."""
KEPT = (
    "rmse_mm",
    "overshoot_pct",
    "settling_time_s",
    "tension_violation_max_mN",
    "tension_violation_time_s",
    "fallbacks",
    "solve_time_median_ms",
)
"""The metrics recorded per point and scene."""


def point_key(slug: str, horizon: int, weight_y: float, weight_du: float) -> str:
    """A TOML bare key naming one grid point: ``nmpc_h20_y1e6_du3em10``."""

    def tag(v: float) -> str:
        return f"{v:.0e}".replace("e+0", "e").replace("e-0", "em").replace("-", "m")

    return f"{slug}_h{horizon}_y{tag(weight_y)}_du{tag(weight_du)}"


def scene_text(scene: str, points: Mapping[str, Mapping[str, object]]) -> str:
    """The packaged ``scene`` with its controllers replaced by ``lqi`` and ``points``
    (key -> the controller's own table: ``type`` and settings)."""
    text = resolve_scenario(scene).read_text(encoding="utf-8")
    text = re.sub(r"\[control\.controllers\.\w+\]\n(\w.*\n)*\n*", "", text)
    tables = ["[control.controllers.lqi]\n"]
    for key, own in points.items():
        lines = [f"[control.controllers.{key}]"]
        lines += [
            f"{k} = {json.dumps(v) if isinstance(v, str) else repr(v)}" for k, v in own.items()
        ]
        tables.append("\n".join(lines) + "\n")
    head, sep, tail = text.partition("[outputs")
    return head.rstrip("\n") + "\n\n" + "\n".join(tables) + ("\n" + sep + tail if sep else "")


def run_points(
    points: Mapping[str, Mapping[str, object]], scenes: Sequence[str] = SCENES
) -> dict[str, dict[str, dict[str, float]]]:
    """Every point (and ``lqi``) on every scene: scene -> key -> :data:`KEPT` metrics."""
    out = {}
    for scene in scenes:
        sc = parse_scenario(scene_text(scene, points), f"{scene}-tuning.toml")
        metrics = run_closed_loop_scene(sc, Path(".")).metrics
        out[scene] = {
            key: {m: float(metrics[f"{key}_{m}"]) for m in KEPT} for key in ["lqi", *points]
        }
    return out


def excess(rows: Mapping[str, Mapping[str, float]]) -> float:
    """How far a point's rows (scene -> metrics) are from admissible: the overshoot and
    violation beyond their bounds, each divided by its bound, plus the fallbacks (0 if
    admissible)."""
    over = rows["control-length"]["overshoot_pct"] - OVERSHOOT_MAX_PCT
    viol = rows["control-tension"]["tension_violation_max_mN"] - VIOLATION_MAX_MN
    falls = sum(r["fallbacks"] for r in rows.values())
    return max(0.0, over) / OVERSHOOT_MAX_PCT + max(0.0, viol) / VIOLATION_MAX_MN + falls


def score(rows: Mapping[str, Mapping[str, float]], lqi: Mapping[str, Mapping[str, float]]):
    """Mean over the scenes of the point's RMSE divided by LQI's [-]."""
    return sum(rows[s]["rmse_mm"] / lqi[s]["rmse_mm"] for s in rows) / len(rows)


def choose(
    candidates: Mapping[str, Mapping[str, Mapping[str, float]]],
    lqi: Mapping[str, Mapping[str, float]],
    distance: Mapping[str, float],
) -> str:
    """The key of the winning point (see the module docstring): ``candidates`` maps a key
    to its rows (scene -> metrics), ``lqi`` holds LQI's rows, ``distance`` each key's
    distance from the current defaults (ties go to the nearest)."""
    return min(
        candidates,
        key=lambda k: (
            excess(candidates[k]),
            round(score(candidates[k], lqi), SCORE_DIGITS),
            distance[k],
        ),
    )


def distance_from_defaults(settings: Mapping[str, object]) -> float:
    """Decades between a point's weights and its controller's current defaults
    (:class:`~sarcomere.controllers.nmpc.NMPCSettings`,
    :class:`~sarcomere.controllers.lmpc.LMPCSettings`), summed over both weights."""
    from sarcomere.controllers.lmpc import LMPCSettings
    from sarcomere.controllers.nmpc import NMPCSettings

    d = {"nmpc": NMPCSettings(), "lmpc": LMPCSettings()}[settings["type"]]
    return sum(abs(math.log10(settings[w] / getattr(d, w))) for w in ("weight_y", "weight_du"))


def study(
    weights_y: Sequence[float] = WEIGHTS_Y,
    weights_du: Sequence[float] = WEIGHTS_DU,
    horizons: Sequence[int] = HORIZONS,
    horizon_default: int = 20,
) -> dict:
    """Both stages for both MPCs on the grid ``weights_y`` x ``weights_du`` and the
    ``horizons``; returns what ``mpc_tuning.json`` holds (the grid included)."""
    grid = {
        point_key(slug, horizon_default, wy, wdu): {
            "type": slug,
            "horizon": horizon_default,
            "weight_y": wy,
            "weight_du": wdu,
        }
        for slug in CONTROLLERS
        for wy in weights_y
        for wdu in weights_du
    }
    tic = time.perf_counter()
    stage1 = run_points(grid)
    wall1 = time.perf_counter() - tic
    lqi = {s: stage1[s]["lqi"] for s in SCENES}
    rows = {k: {s: stage1[s][k] for s in SCENES} for k in grid}
    best = {}
    for slug in CONTROLLERS:
        keys = [k for k in grid if grid[k]["type"] == slug]
        near = {k: distance_from_defaults(grid[k]) for k in keys}
        best[slug] = choose({k: rows[k] for k in keys}, lqi, near)
    others = {
        point_key(slug, h, grid[k]["weight_y"], grid[k]["weight_du"]): {**grid[k], "horizon": h}
        for slug, k in best.items()
        for h in horizons
        if h != horizon_default
    }
    tic = time.perf_counter()
    more = run_points(others)
    wall2 = time.perf_counter() - tic
    rows |= {k: {s: more[s][k] for s in SCENES} for k in others}
    settings = grid | others
    chosen = {}
    for slug, final in best.items():
        mine = [k for k in others if others[k]["type"] == slug and excess(rows[k]) == 0]
        alt = min(mine, key=lambda k: score(rows[k], lqi), default=None)
        if alt and score(rows[alt], lqi) < (1 - HORIZON_GAIN) * score(rows[final], lqi):
            final = alt
        chosen[slug] = {
            "key": final,
            "settings": settings[final],
            "admissible": excess(rows[final]) == 0,
            "score": score(rows[final], lqi),
        }
    return {
        "scenes": list(SCENES),
        "grid": {
            "weights_y": list(weights_y),
            "weights_du": list(weights_du),
            "horizons": list(horizons),
        },
        "criterion": {
            "overshoot_max_pct": OVERSHOOT_MAX_PCT,
            "violation_max_mN": VIOLATION_MAX_MN,
            "score": "mean over the scenes of rmse / rmse_lqi",
            "horizon_gain": HORIZON_GAIN,
        },
        "lqi": lqi,
        "stage1": {k: {"settings": grid[k], "rows": rows[k]} for k in grid},
        "stage2": {k: {"settings": others[k], "rows": rows[k]} for k in others},
        "chosen": chosen,
        "wall_time_s": {"stage1": wall1, "stage2": wall2},
    }


def table(record: dict) -> str:
    """A markdown table of every point: both scenes' RMSE, overshoot, violation, score."""
    lqi = record["lqi"]
    rows = [
        "| point | horizon | weight_y | weight_du | length rmse mm | length overshoot % "
        "| tension rmse mm | tension violation mN | fallbacks | score (rmse / LQI) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    chosen = {c["key"] for c in record["chosen"].values()}
    for key, p in {**record["stage1"], **record["stage2"]}.items():
        s, r = p["settings"], p["rows"]
        length, tension = r["control-length"], r["control-tension"]
        mark = " **chosen**" if key in chosen else ""
        rows.append(
            f"| {s['type']}{mark} | {s['horizon']} | {s['weight_y']:.0e} | {s['weight_du']:.0e} "
            f"| {length['rmse_mm']:.3f} | {length['overshoot_pct']:.1f} "
            f"| {tension['rmse_mm']:.3f} | {tension['tension_violation_max_mN']:.2f} "
            f"| {int(length['fallbacks'] + tension['fallbacks'])} | {score(r, lqi):.3f} |"
        )
    rows.append(
        f"| lqi (reference) | - | - | - | {lqi['control-length']['rmse_mm']:.3f} "
        f"| {lqi['control-length']['overshoot_pct']:.1f} | {lqi['control-tension']['rmse_mm']:.3f} "
        f"| {lqi['control-tension']['tension_violation_max_mN']:.2f} | 0 | 1 |"
    )
    return "\n".join(rows)


def main(argv: Sequence[str] | None = None) -> int:
    """``--out DIR``: run :func:`study`, write ``mpc_tuning.json``, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench/mpc_tuning"))
    parser.add_argument("--weights-y", type=float, nargs="+", default=WEIGHTS_Y)
    parser.add_argument("--weights-du", type=float, nargs="+", default=WEIGHTS_DU)
    parser.add_argument("--horizons", type=int, nargs="+", default=HORIZONS)
    args = parser.parse_args(argv)
    record = study(args.weights_y, args.weights_du, args.horizons)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "mpc_tuning.json").write_text(json.dumps(record, indent=2))
    print(table(record))
    for slug, c in record["chosen"].items():
        print(f"{slug}: {c['settings']} admissible={c['admissible']} score={c['score']:.3f}")
    print(f"wall time: {record['wall_time_s']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
