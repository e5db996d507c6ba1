"""The joint-control scene's closed loop in CPU time against real time (issue 26): the
packaged scene (plant on Radau IIA) and the same on CVODES, interleaved, ``--repeats``
runs each; prints the median real-time factor (simulated over process time of the loop,
the scene's ``lqi_real_time_factor``) and the largest relative difference of the other
metrics between the two integrators.

Usage: ``python benchmarks/joint_control_speed.py --repeats 3``
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from sarcomere.scenarios import load_scenario, parse_scenario, run
from sarcomere.scenarios.catalog import packaged_scenarios


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    text = packaged_scenarios()["joint-control"].read_text()
    scenes = {
        "radau": load_scenario("joint-control"),
        "cvodes": parse_scenario(text.replace('method = "radau"', 'method = "cvodes"')),
    }
    rtf, last = {k: [] for k in scenes}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            for key, sc in scenes.items():
                out = Path(tmp) / f"{key}{i}"
                run(sc, out, quiet=True)
                m = json.loads((out / "summary.json").read_text())["metrics"]
                rtf[key].append(m["lqi_real_time_factor"])
                last[key] = m
    for key, values in rtf.items():
        print(f"{key}: real-time factor median {np.median(values):.1f}x of {values}")
    diff = max(
        abs(last["radau"][k] / last["cvodes"][k] - 1)
        for k, v in last["cvodes"].items()
        if isinstance(v, float) and v and "cpu" not in k and "time_factor" not in k
    )
    print(f"largest relative difference of the other metrics: {diff:.2g}")


if __name__ == "__main__":
    main()
