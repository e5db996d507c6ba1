"""The ``sarcomere`` command line: ``list``, ``run SCENARIO``, ``calibrate``, ``bench``,
``export-fmu``, ``linearize SCENARIO``.

Subcommands are rows of :data:`COMMANDS` (name, help, handler, add_arguments); add one by
appending a :class:`Command`. A :class:`~sarcomere.dynamics.errors.SarcomereError` prints
one ``error: ...`` line to stderr and exits with status 2; other exceptions propagate.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from sarcomere.dynamics.errors import SarcomereError

from . import bench, calibrate, export_fmu, linearize
from .loader import load_scenario, packaged_scenarios
from .outdir import check_out_dir
from .output import version
from .runner import run
from .threads import limited_blas


@dataclass(frozen=True)
class Command:
    """One subcommand.

    Parameters
    ----------
    name : str
        Subcommand word, e.g. ``"run"``.
    help : str
        One line for ``sarcomere --help``.
    handler : callable
        ``handler(args) -> int`` does the work and returns the exit status.
    add_arguments : callable, optional
        ``add_arguments(parser)`` declares the subcommand's arguments.
    """

    name: str
    help: str
    handler: Callable[[argparse.Namespace], int]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None


def _list(args: argparse.Namespace) -> int:
    rows = [(name, load_scenario(name)) for name in packaged_scenarios()]
    width = max((len(name) for name, _ in rows), default=0)
    for name, sc in rows:
        print(f"{name:<{width}}  {sc.kind:<11}  {sc.description}")
    return 0


def _run_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "scenario", help="scenario file (path/to/file.toml) or packaged name (see 'list')"
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        help="output folder (default: out/<scenario name>)",
    )
    parser.add_argument("--quiet", action="store_true", help="do not print the summary")


def _run(args: argparse.Namespace) -> int:
    out = None if args.out is None else check_out_dir(args.out, "--out")  # before computing
    run(args.scenario, out, quiet=args.quiet)
    return 0


COMMANDS: list[Command] = [
    Command("list", "list the packaged scenarios", _list),
    Command("run", "run a scenario and write summary.json, CSV and plots", _run, _run_arguments),
    Command(
        "calibrate",
        "fit A_p, A_r, k_s to the paper's three measured targets (IPOPT)",
        calibrate.handler,
        calibrate.add_arguments,
    ),
    Command(
        "bench",
        "numerical studies: work-precision, stability, mpc",
        bench.handler,
        bench.add_arguments,
    ),
    Command(
        "export-fmu",
        "export a transient scenario's model as an FMU (FMI 2.0 or 3.0, ME and CS)",
        export_fmu.handler,
        export_fmu.add_arguments,
    ),
    Command(
        "linearize",
        "exact linearisation of a scene's model: poles by mode, Bode plot, named matrices",
        linearize.handler,
        linearize.add_arguments,
    ),
]


def build_parser(commands: Sequence[Command] = COMMANDS) -> argparse.ArgumentParser:
    """The argument parser with one subparser per command."""
    parser = argparse.ArgumentParser(
        prog="sarcomere",
        description="Lumped models of artificial pneumatic muscles: run scenarios.",
    )
    parser.add_argument("--version", action="version", version=f"sarcomere {version()}")
    subs = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for cmd in commands:
        sub = subs.add_parser(cmd.name, help=cmd.help, description=cmd.help)
        if cmd.add_arguments is not None:
            cmd.add_arguments(sub)
        sub.set_defaults(handler=cmd.handler)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sarcomere`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        with limited_blas():
            return args.handler(args)
    except SarcomereError as exc:
        message = " ".join(str(exc).split())
        print(f"error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
