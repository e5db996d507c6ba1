"""auto against full on a long run at n = 3: the packaged dither for 150 s (30 000 output
points), where full pauses at its budget (docs/numerics.md, "Full first").

    OPENBLAS_NUM_THREADS=1 python benchmarks/auto_long_run.py [--finish-s S] [--repeats 5]

Prints the level auto chose and the end-to-end medians (scene run, CSV and plots
included), auto and full interleaved in one process. ``--finish-s 0`` turns finishing a
paused full run off (the behaviour before it).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from sarcomere.dynamics.fidelity import policy
from sarcomere.scenarios import parse_scenario, resolve_scenario, run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--finish-s", type=float, default=policy.FULL_FIRST_FINISH_S)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    policy.FULL_FIRST_FINISH_S = args.finish_s
    base = resolve_scenario("dither-50g-auto").read_text(encoding="utf-8")
    base = base.replace('stop_time = "30 s"', 'stop_time = "150 s"')
    full = base.replace('fidelity = "auto"', 'fidelity = "full"')
    texts = {"auto": base, "full": full.replace('tolerance = "1 %"\n', "")}
    times: dict[str, list[float]] = {k: [] for k in texts}
    chosen = None
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            for kind, text in texts.items():
                tic = time.perf_counter()
                out = run(
                    parse_scenario(text, f"{kind}.toml"), Path(tmp) / f"{kind}{r}", quiet=True
                )
                times[kind].append(time.perf_counter() - tic)
                chosen = out.fidelity if kind == "auto" else chosen
    med = {k: statistics.median(v) for k, v in times.items()}
    print(
        f"auto chose {chosen}; auto {med['auto']:.3f} s, full {med['full']:.3f} s, "
        f"x{med['auto'] / med['full']:.2f}"
    )


if __name__ == "__main__":
    main()
