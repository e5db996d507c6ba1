"""The ``sarcomere`` command line: ``list``, ``run SCENARIO``, ``study STUDY``,
``calibrate``, ``bench``, ``export-fmu``, ``linearize SCENARIO``.

Subcommands are rows of :data:`COMMANDS` (name, help, handler, add_arguments); add one by
appending a :class:`Command`. A command's module is imported only when the command line
names it: ``--version``, ``--help``, ``list`` and argument errors load no model library
and answer at once (BENCHMARKS.md, start-up). A
:class:`~sarcomere.dynamics.errors.SarcomereError` prints one ``error: ...`` line to stderr
and exits with status 2; Ctrl-C and SIGTERM print one line and exit with 130 and 143;
other exceptions propagate.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import import_module

from sarcomere.dynamics.errors import SarcomereError

Hook = Callable | str
"""A callable, or ``"module:attribute"`` naming one, imported only when needed."""


@dataclass(frozen=True)
class Command:
    """One subcommand.

    Parameters
    ----------
    name : str
        Subcommand word, e.g. ``"run"``.
    help : str
        One line for ``sarcomere --help``.
    handler : callable or str
        ``handler(args) -> int`` does the work and returns the exit status; or
        ``"module:attribute"`` naming it, imported when the command runs.
    add_arguments : callable or str, optional
        ``add_arguments(parser)`` declares the subcommand's arguments (or its
        ``"module:attribute"``); called only when the command line names this command, so
        ``sarcomere --help`` and the other commands never import its module.
    """

    name: str
    help: str
    handler: Hook
    add_arguments: Hook | None = None


def _resolve(hook: Hook) -> Callable:
    """The callable ``hook`` stands for."""
    if callable(hook):
        return hook
    module, _, attribute = hook.partition(":")
    return getattr(import_module(module), attribute)


def _list(args: argparse.Namespace) -> int:
    from .catalog import heading, packaged_scenarios  # no model, no CasADi: starts at once

    rows = [(name, heading(res)) for name, res in packaged_scenarios().items()]
    width = max((len(name) for name, _ in rows), default=0)
    for name, head in rows:
        print(f"{name:<{width}}  {head.get('kind', '?'):<11}  {head.get('description', '')}")
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
    parameters_argument(parser)


def parameters_argument(parser: argparse.ArgumentParser) -> None:
    """``--parameters FILE``: a parameter file (``sarcomere fit``'s ``fitted.toml``)
    included after the scene's own includes; the scene's ``[parameters]`` override it."""
    parser.add_argument(
        "--parameters",
        metavar="FILE",
        help="parameter file (e.g. a fit's fitted.toml); the scene's [parameters] override it",
    )


def _run(args: argparse.Namespace) -> int:
    from .outdir import check_out_dir

    out = None if args.out is None else check_out_dir(args.out, "--out")  # before computing
    from .runner import run

    scenario = args.scenario
    if args.parameters is not None:
        from .loader import load_scenario, with_parameter_file

        scenario = with_parameter_file(load_scenario(scenario), args.parameters)
    run(scenario, out, quiet=args.quiet)
    return 0


def _count(text: str) -> int:
    """A whole number >= 1 (argparse type: a bad one is an argument error, at once)."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number >= 1")
    return int(text)


def _study_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", help="study TOML, scene TOML with [study], or packaged name")
    parser.add_argument("--out", metavar="DIR", required=True, help="results folder (resumed)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", metavar="N", type=_count, help="local worker processes")
    where.add_argument("--scheduler", metavar="ADDRESS", help="tcp://HOST:PORT of a Dask cluster")
    parser.add_argument("--max-samples", metavar="N", type=_count, help="cap on the samples")
    parser.add_argument(
        "--max-store-mb", metavar="MB", type=_count, help="cap on the store's size [MB] (2147)"
    )
    plots = parser.add_mutually_exclusive_group()
    plots.add_argument("--no-plots", action="store_true", help="summary.json without figures")
    plots.add_argument(
        "--plots-only", action="store_true", help="draw the figures from the store, compute nothing"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress line, no summary")
    parameters_argument(parser)


def _study(args: argparse.Namespace) -> int:
    from .explore.study import Study

    study = Study.from_file(args.study, args.parameters)
    caps = {"max_samples": args.max_samples}
    if args.max_store_mb is not None:
        caps["max_store_bytes"] = args.max_store_mb * 1_000_000
    if args.plots_only:
        ds = study.replot(args.out)
    else:
        where = (args.out, args.workers, args.scheduler, not args.quiet)
        ds = study.run(*where, plots=not args.no_plots, **caps)
    if not args.quiet:
        failed = int((ds["status"] != 0).sum())
        print(f"study {study.definition.name}: {ds['status'].size} samples, {failed} failed")
    return 0


COMMANDS: list[Command] = [
    Command("list", "list the packaged scenarios", _list),
    Command("run", "run a scenario and write summary.json, CSV and plots", _run, _run_arguments),
    Command(
        "study",
        "design study (grid, samples, sensitivity) on Dask into a resumable Zarr store",
        _study,
        _study_arguments,
    ),
    Command(
        "calibrate",
        "fit A_p, A_r, k_s to the paper's three measured targets (the fit engine)",
        "sarcomere.scenarios.calibrate:handler",
        "sarcomere.scenarios.calibrate:add_arguments",
    ),
    Command(
        "fit",
        "fit model parameters to measured time series and static curves, with uncertainty",
        "sarcomere.scenarios.fit.command:handler",
        "sarcomere.scenarios.fit.command:add_arguments",
    ),
    Command(
        "bench",
        "numerical studies: work-precision, stability, mpc",
        "sarcomere.scenarios.bench:handler",
        "sarcomere.scenarios.bench:add_arguments",
    ),
    Command(
        "export-fmu",
        "export a transient scenario's model as an FMU (FMI 2.0 or 3.0, ME and CS)",
        "sarcomere.scenarios.export_fmu:handler",
        "sarcomere.scenarios.export_fmu:add_arguments",
    ),
    Command(
        "linearize",
        "exact linearisation of a scene's model: poles by mode, Bode plot, named matrices",
        "sarcomere.scenarios.linearize:handler",
        "sarcomere.scenarios.linearize:add_arguments",
    ),
]


def _named(argv: Sequence[str], commands: Sequence[Command]) -> str | None:
    """The command word of ``argv`` (its first non-option), or None."""
    names = {cmd.name for cmd in commands}
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in names else None


def build_parser(
    commands: Sequence[Command] = COMMANDS, argv: Sequence[str] | None = None
) -> argparse.ArgumentParser:
    """The argument parser with one subparser per command.

    Only the command ``argv`` names gets its arguments declared (its module imported);
    with ``argv`` None every command does.
    """
    from .catalog import version

    parser = argparse.ArgumentParser(
        prog="sarcomere",
        description="Lumped models of artificial pneumatic muscles: run scenarios.",
    )
    parser.add_argument("--version", action="version", version=f"sarcomere {version()}")
    subs = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    named = None if argv is None else _named(argv, commands)
    for cmd in commands:
        sub = subs.add_parser(cmd.name, help=cmd.help, description=cmd.help)
        if cmd.add_arguments is not None and (argv is None or cmd.name == named):
            _resolve(cmd.add_arguments)(sub)
        sub.set_defaults(handler=cmd.handler)
    return parser


_OPTION, _SIGNED = re.compile(r"--[^=]+$"), re.compile(r"-\.?\d")


def _signed_values(argv: list[str]) -> list[str]:
    """``--opt -1MPa`` as ``--opt=-1MPa``: argparse takes a word starting with ``-`` and
    a letter for an option (only bare numbers pass), so a negative quantity would be an
    argument error instead of the option's own range message. No command has a
    positional argument that starts with ``-`` and a digit."""
    out: list[str] = []
    for word in argv:
        if out and _OPTION.match(out[-1]) and _SIGNED.match(word):
            out[-1] = f"{out[-1]}={word}"
        else:
            out.append(word)
    return out


class Terminated(BaseException):
    """SIGTERM arrived: unwinds like Ctrl-C, so staged output folders are removed."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sarcomere`` console script; returns the exit status.

    A :class:`SarcomereError` prints one ``error:`` line (status 2); Ctrl-C and SIGTERM
    print one line, leave no temporary folder (see :mod:`.outdir`) and return the shell's
    conventional 130 and 143.
    """
    argv = _signed_values(sys.argv[1:] if argv is None else list(argv))
    args = build_parser(argv=argv).parse_args(argv)
    from .threads import limited_blas

    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        with limited_blas():
            status = _resolve(args.handler)(args)
        sys.stdout.flush()  # here, not at exit: a closed pipe is caught below
        return status
    except SarcomereError as exc:
        message = " ".join(str(exc).split())
        print(f"error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sarcomere: interrupted by SIGINT (Ctrl-C)", file=sys.stderr)
        return 128 + signal.SIGINT
    except Terminated:
        print("sarcomere: terminated by SIGTERM", file=sys.stderr)
        return 128 + signal.SIGTERM
    except BrokenPipeError:  # `sarcomere list | head -1`: the reader left, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return 128 + signal.SIGPIPE
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
