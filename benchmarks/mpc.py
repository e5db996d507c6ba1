"""MPC speed on the length-control scene: ``sarcomere bench mpc`` as a script.

The study itself is :mod:`sarcomere.scenarios.studies.mpc_speed` (installed with the package, so
the CLI runs it too). Usage::

    python benchmarks/mpc.py --out out/bench/mpc [--quick]

writes ``mpc.json`` (every variant: time per step, tracking, fallbacks; the RTI's feedback
latency and preparation, wall and CPU, in Python and compiled, also interleaved sample by
sample; the prediction fidelity comparison) and ``summary.json``.

    python benchmarks/mpc.py --scaling --out out/bench/mpc [--n 3 5 8 10] [--compiled-n 3 10]
        [--samples 60]

writes ``mpc_scaling.json``: the RTI's CPU time per step against the chain length n, the
dense and the factored lift in Python and the compiled one side by side, with their build
and compile times (:mod:`sarcomere.scenarios.studies.mpc_scaling`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sarcomere.scenarios.cli import main


def scaling(argv: list[str]) -> int:
    from sarcomere.scenarios.studies import mpc_scaling

    ap = argparse.ArgumentParser()
    ap.add_argument("--scaling", action="store_true")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--n", type=int, nargs="+", default=[3, 5, 8, 10])
    ap.add_argument("--compiled-n", type=int, nargs="+", default=[3, 10])
    ap.add_argument("--samples", type=int, default=60)
    a = ap.parse_args(argv)
    rows = mpc_scaling.study(a.n, a.samples, a.compiled_n)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "mpc_scaling.json").write_text(json.dumps(rows, indent=1))
    for row in rows:
        print(json.dumps(row))
    return 0


if __name__ == "__main__":
    args = sys.argv[1:]
    sys.exit(scaling(args) if "--scaling" in args else main(["bench", "mpc", *args]))
