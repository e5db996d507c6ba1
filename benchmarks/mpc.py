"""MPC speed on the length-control scene: ``sarcomere bench mpc`` as a script.

The study itself is :mod:`sarcomere.scenarios.studies.mpc_speed` (installed with the package, so
the CLI runs it too). Usage::

    python benchmarks/mpc.py --out out/bench/mpc [--quick]

writes ``mpc.json`` (every variant: time per step, tracking, fallbacks; the RTI's feedback
latency and preparation, wall and CPU, in Python and compiled, also interleaved sample by
sample; the prediction fidelity comparison) and ``summary.json``.
"""

from __future__ import annotations

import sys

from sarcomere.scenarios.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "mpc", *sys.argv[1:]]))
