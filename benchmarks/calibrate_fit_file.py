"""The calibration through the packaged fit file against the library's own fit (issue 25,
"Calibration": the same parameters to 1e-8, within 1.5x of the time).

Each round runs, in fresh processes and alternating which goes first:

* ``library``: ``calibration.calibrate()`` (the fit defined in code, then the
  sensitivities and the compliance split);
* ``fit file``: ``scenarios.calibrate.calibrate_file()`` (what ``sarcomere calibrate``
  runs: fit-paper.toml through ``Fit``, then the same verification and assessment).

Reported: the CPU seconds of each whole process (imports included: what a user of the
command waits for) and of the call alone, medians over the rounds, their ratios, and the
largest relative difference of the three parameters. Usage::

    python benchmarks/calibrate_fit_file.py [--rounds 7]

Results: BENCHMARKS.md section 15 ("The calibration through fit-paper").
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
t0 = time.process_time()
if sys.argv[1] == "library":
    from sarcomere.dynamics.calibration import calibrate
else:
    from sarcomere.scenarios.calibrate import calibrate_file as calibrate
t1 = time.process_time()
res = calibrate()
t2 = time.process_time()
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"call": t2 - t1, "process": ru.ru_utime + ru.ru_stime, "fitted": res.fitted}))
"""

MODES = ("library", "fit file")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args(argv)
    runs: dict[str, list[dict]] = {m: [] for m in MODES}
    for r in range(args.rounds):
        for mode in MODES if r % 2 == 0 else MODES[::-1]:
            done = subprocess.run(
                [sys.executable, "-c", CHILD, mode.split()[0]],
                capture_output=True,
                text=True,
                check=True,
            )
            runs[mode].append(json.loads(done.stdout.strip().splitlines()[-1]))
    med = {
        m: {k: statistics.median(x[k] for x in runs[m]) for k in ("call", "process")} for m in MODES
    }
    for m in MODES:
        print(
            f"{m:>9}: process {med[m]['process']:.3f} s CPU, call {med[m]['call']:.3f} s CPU "
            f"(medians of {args.rounds})"
        )
    lib, file = med["library"], med["fit file"]
    print(
        f"ratio fit file / library: process {file['process'] / lib['process']:.3f}, "
        f"call {file['call'] / lib['call']:.3f}"
    )
    a, b = runs["library"][0]["fitted"], runs["fit file"][0]["fitted"]
    print(f"largest relative parameter difference: {max(abs(b[k] / a[k] - 1) for k in a):.2g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
