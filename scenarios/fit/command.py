"""``sarcomere fit FIT.toml --out DIR [--scheduler ADDR] [--workers N] [--no-plots]``."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The fit file, ``--out``, ``--scheduler``, ``--workers``, ``--no-plots``,
    ``--no-profiles``."""
    parser.add_argument("fit", metavar="FIT.toml", help="the fit file (docs/fitting.md)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--scheduler", metavar="ADDR", help="a running Dask scheduler for the starts and profiles"
    )
    parser.add_argument(
        "--workers", type=int, metavar="N", help="embedded cluster's worker processes"
    )
    parser.add_argument("--no-plots", action="store_true", help="write no PNG files")
    parser.add_argument(
        "--no-profiles", action="store_true", help="skip the profile likelihoods (Fisher only)"
    )


def handler(args: argparse.Namespace) -> int:
    """Check the fit file and its data (one-line errors, exit 2), fit, write ``--out``."""
    from ..explore.engine import check_cluster_arguments
    from .run import Fit

    check_cluster_arguments(args.workers, args.scheduler)
    fit = Fit.from_file(args.fit)
    res = fit.run(
        args.out,
        scheduler=args.scheduler,
        workers=args.workers,
        plots=not args.no_plots,
        profiles=not args.no_profiles,
    )
    print(
        f"fit '{fit.built.spec.name}': {res.converged_starts} of {len(res.starts)} starts "
        f"reached the best optimum, {res.equivalent_starts} within chi-squared 1 of it "
        f"({sum(s.dropped for s in res.starts)} dropped); "
        f"chi2 = {res.solution.cost:.6g}; {res.wall_time:.1f} s"
    )
    for k, (name, (value, unit)) in enumerate(res.estimates.items()):
        lo, hi = res.fisher.interval[k]
        print(f"  {name} = {value:.6g} {unit}  [{lo:.4g}, {hi:.4g}]  {res.verdicts[k]['verdict']}")
    print(f"wrote {args.out}/: {', '.join(res.files)}")
    return 0
