"""Start-up of the ``sarcomere`` command line and the README's main job, end to end.

Each command runs as a fresh process (the installed console script beside this
interpreter), ``--repeats`` times, interleaved (one round runs every command once, so a
change of machine load hits all of them alike); reported are the median wall time and
the median CPU time (user + system of the child: less sensitive to other processes on a
shared machine than the wall time). The interpreter alone (``python -c pass``) and the
imports of the heavy libraries are measured the same way, side by side. Last, one
``python -X importtime`` run of ``sarcomere run step-50g`` gives the imports that cost
the most (cumulative time of each top-level import, and the packages' own time).

With ``--baseline SITE`` (an older sarcomere installed with ``pip install --no-deps
--target SITE``) the same commands of that version run in the same rounds, through
``python -m sarcomere.scenarios.cli`` with ``PYTHONPATH=SITE``, and the ratios are given.

The load of the machine (``os.getloadavg``) is printed before and after: on a shared
machine the wall times are only comparable within one run of this script.

Usage::

    python benchmarks/startup.py [--repeats 7] [--out out/bench/startup.json]
    git archive 284da84 | tar -x -C /tmp/base-src &&
        pip install --no-deps --target /tmp/base-site /tmp/base-src &&
        python benchmarks/startup.py --baseline /tmp/base-site
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SARCOMERE = {  # label -> arguments of the sarcomere command line
    "--version": ["--version"],
    "--help": ["--help"],
    "list": ["list"],
    "run (argument error)": ["run"],
    "run step-50g --out DIR": ["run", "step-50g", "--out", "{out}"],
}


def commands(script: str, out: str) -> dict[str, list[str]]:
    """Label -> argv of every measured command."""
    py = sys.executable
    return {
        "python -c pass": [py, "-c", "pass"],
        **{
            f"sarcomere {label}": [script, *(a.format(out=out) for a in argv)]
            for label, argv in SARCOMERE.items()
        },
        "python -c 'import casadi'": [py, "-c", "import casadi"],
        "python -c 'import matplotlib.figure'": [py, "-c", "import matplotlib.figure"],
        "python -c 'import control'": [py, "-c", "import control"],
    }


def baseline_commands(site: str, out: str) -> dict[str, list[str]]:
    """The sarcomere commands of the version installed in ``site`` (label -> argv)."""
    cli = [sys.executable, "-m", "sarcomere.scenarios.cli"]
    return {
        f"baseline: sarcomere {label}": [*cli, *(a.format(out=out) for a in argv)]
        for label, argv in SARCOMERE.items()
    }


def timed(argv: list[str], env: dict | None = None) -> tuple[float, float]:
    """Wall time and child CPU time (user + system) of one run of ``argv``, s."""
    tic = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    _, _, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - tic
    proc.returncode = 0  # reaped by wait4
    return wall, usage.ru_utime + usage.ru_stime


def import_breakdown(script: str, out: str, top: int) -> dict:
    """The ``-X importtime`` record of one ``run step-50g``: top-level imports by
    cumulative time, and packages by their own time summed over their modules, us."""
    code = f"import sys; sys.argv = {[script, 'run', 'step-50g', '--quiet', '--out', out]!r};"
    code += "from sarcomere.scenarios.cli import main; main(sys.argv[1:])"
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code], capture_output=True, text=True
    )
    rows = re.findall(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", done.stderr)
    first = [(int(cum), name) for _, cum, pad, name in rows if len(pad) <= 1]
    own: dict[str, int] = {}
    for self_us, _, _, name in rows:
        package = name.split(".")[0]
        if package == "sarcomere":
            package = ".".join(name.split(".")[:2])
        own[package] = own.get(package, 0) + int(self_us)
    return {
        "total_us": sum(int(r[0]) for r in rows),
        "top_level_cumulative_us": sorted(first, reverse=True)[:top],
        "package_self_us": sorted(((v, k) for k, v in own.items()), reverse=True)[:top],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--top", type=int, default=12, help="rows of the import breakdown")
    parser.add_argument("--out", type=Path, help="JSON record of the numbers")
    parser.add_argument("--baseline", metavar="SITE", help="an older version's install folder")
    args = parser.parse_args()
    script = str(Path(sys.executable).parent / "sarcomere")
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "step-50g")
        cmds = commands(script, out)
        envs = dict.fromkeys(cmds)
        if args.baseline:
            old = baseline_commands(args.baseline, out + "-baseline")
            cmds.update(old)
            envs.update(dict.fromkeys(old, {**os.environ, "PYTHONPATH": args.baseline}))
        samples: dict[str, list[tuple[float, float]]] = {k: [] for k in cmds}
        for _ in range(args.repeats):
            for label, argv in cmds.items():
                samples[label].append(timed(argv, envs[label]))
        imports = import_breakdown(script, out, args.top)
    load_after = os.getloadavg()
    table = {
        label: {
            "wall_median_s": statistics.median(w for w, _ in runs),
            "wall_min_s": min(w for w, _ in runs),
            "cpu_median_s": statistics.median(c for _, c in runs),
        }
        for label, runs in samples.items()
    }
    print(f"load average (1, 5, 15 min) before {load_before}, after {load_after}")
    print(f"{args.repeats} interleaved rounds; median wall, min wall, median CPU (user+sys)")
    print("| command | wall median [s] | wall min [s] | CPU median [s] |\n|---|---|---|---|")
    for label, row in table.items():
        print(
            f"| `{label}` | {row['wall_median_s']:.3f} | {row['wall_min_s']:.3f} "
            f"| {row['cpu_median_s']:.3f} |"
        )
    for label in SARCOMERE if args.baseline else ():
        new, old = table[f"sarcomere {label}"], table[f"baseline: sarcomere {label}"]
        print(
            f"baseline / now, `{label}`: wall {old['wall_median_s'] / new['wall_median_s']:.1f}x, "
            f"CPU {old['cpu_median_s'] / new['cpu_median_s']:.1f}x"
        )
    print(f"\n`-X importtime` of `run step-50g`: {imports['total_us'] / 1e6:.2f} s of imports")
    print("| top-level import | cumulative [s] |\n|---|---|")
    for us, name in imports["top_level_cumulative_us"]:
        print(f"| `{name}` | {us / 1e6:.3f} |")
    print("\n| package (own time of all its modules) | [s] |\n|---|---|")
    for us, name in imports["package_self_us"]:
        print(f"| `{name}` | {us / 1e6:.3f} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        record = {"load": [load_before, load_after], "commands": table, "imports": imports}
        args.out.write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
