"""The MPCs' default weights by a stated criterion: a coarse grid on control-length and
control-tension (BENCHMARKS.md, section "MPC tuning").

The study itself is ``benchmarks/studies/mpc_tuning.py`` (not installed with the package).
Usage::

    OPENBLAS_NUM_THREADS=1 nice python benchmarks/mpc_tuning.py --out out/bench/mpc_tuning

writes ``mpc_tuning.json`` (every grid point's metrics on both scenes, LQI's, the choice)
and prints the markdown table BENCHMARKS.md holds.
"""

from __future__ import annotations

import sys

from studies.mpc_tuning import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
