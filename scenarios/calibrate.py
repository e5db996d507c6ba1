"""``sarcomere calibrate``: fit the effective APS parameters to the paper's targets."""

from __future__ import annotations

import argparse
import json
import time

from sarcomere.dynamics.calibration import TARGETS, calibrate

from .outdir import check_out_dir, staged


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--out DIR`` (default out/calibration) and ``--verbose`` (IPOPT's log)."""
    parser.add_argument(
        "--out",
        default="out/calibration",
        metavar="DIR",
        help="output folder for calibration.json (default: out/calibration)",
    )
    parser.add_argument("--verbose", action="store_true", help="print IPOPT's iterations")


def handler(args: argparse.Namespace) -> int:
    """Run the calibration, write ``DIR/calibration.json`` and print a summary.

    ``--out`` is checked before the fit starts; the folder is replaced only on success.
    """
    out = check_out_dir(args.out, "--out")
    tic = time.perf_counter()
    res = calibrate(verbose=args.verbose)
    wall = time.perf_counter() - tic
    record = {**res.to_dict(), "wall_time_s": wall}
    with staged(out) as tmp:
        (tmp / "calibration.json").write_text(json.dumps(record, indent=2) + "\n")
    path = out / "calibration.json"
    print(f"calibration: IPOPT {res.status}, {wall:.1f} s")
    for name, value in res.fitted.items():
        print(f"  {name:<4} = {value:.6g} {record['fitted'][name]['unit']}")
    for key, target in TARGETS.items():
        print(
            f"  {key:<24} {res.achieved[key]:.6g}  (target {target}, "
            f"residual {100 * res.residuals[key]:+.2e} %)"
        )
    print(
        f"  singular values of d log(targets)/d log(A_p, A_r, k_s): "
        f"{', '.join(f'{s:.3g}' for s in res.singular_values)}"
    )
    print(f"  no influence on these targets: {', '.join(res.not_identifiable)}")
    print(f"wrote {path}")
    return 0
