"""Run a scenario: look up the runner of its kind, time it, write and print the results.

Each scenario ``kind`` ("static", later "equilibrium", "transient") has one runner,
``fn(scenario, out_dir) -> RunOutput``, registered with :func:`register_runner`. The
runner computes; this module checks the output (no NaN), writes ``summary.json``, the
CSV files and the plots (see :mod:`.output`), and prints a short summary.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from importlib import import_module
from pathlib import Path

from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.dynamics.results import Result

from .loader import load_scenario
from .outdir import check_out_dir, staged
from .output import CSV_BYTES_PER_VALUE, RunOutput, check_finite, write_summary, write_timeseries
from .plots import groups_by_unit, plot_groups
from .progress import progress, report
from .spec import Scenario, describe

Runner = Callable[[Scenario, Path], RunOutput]

_RUNNERS: dict[str, Runner] = {}

#: The packaged kinds and the module registering each, imported when a run needs it (a
#: static run never imports the co-simulation master or python-control).
BUILTIN_KINDS = {
    "static": "sarcomere.scenarios.static",
    "equilibrium": "sarcomere.scenarios.equilibrium",
    "transient": "sarcomere.scenarios.transient",
    "closed_loop": "sarcomere.scenarios.control",
    "cosim": "sarcomere.scenarios.cosim",
    "joint_stiffness": "sarcomere.scenarios.joint_stiffness",
    "joint_control": "sarcomere.scenarios.joint_control",
    "recruitment": "sarcomere.scenarios.recruitment",
    "pwm_hold": "sarcomere.scenarios.pwm_hold",
}


def register_runner(kind: str, fn: Runner, *, replace: bool = False) -> None:
    """Make ``fn`` the runner of scenarios with ``[scenario] kind = kind``.

    Parameters
    ----------
    kind : str
        Scenario kind, e.g. ``"static"``.
    fn : callable
        ``fn(scenario, out_dir) -> RunOutput``. It may write extra files into ``out_dir``
        (which exists); it must not write ``summary.json`` or ``timeseries*.csv``.
    replace : bool
        Allow replacing a runner already registered for ``kind``.

    Raises
    ------
    ValueError
        ``kind`` already has a different runner and ``replace`` is false.
    """
    if kind in _RUNNERS and _RUNNERS[kind] is not fn and not replace:
        raise ValueError(f"kind '{kind}' already has runner {_RUNNERS[kind].__qualname__}")
    _RUNNERS[kind] = fn


def runner_kinds() -> tuple[str, ...]:
    """Registered and packaged scenario kinds, sorted."""
    return tuple(sorted({*_RUNNERS, *BUILTIN_KINDS}))


def _runner(sc: Scenario) -> Runner:
    """The runner of ``sc.kind``, importing a packaged kind's module on first use."""
    if sc.kind not in _RUNNERS and sc.kind in BUILTIN_KINDS:
        import_module(BUILTIN_KINDS[sc.kind])  # registers itself
    if sc.kind not in _RUNNERS:
        kinds = ", ".join(runner_kinds())
        raise sc.error(("scenario", "kind"), f"unknown kind '{sc.kind}' (registered: {kinds})")
    return _RUNNERS[sc.kind]


def _selected(scenario: Scenario, key: str, result: Result) -> Result:
    """``result`` restricted to ``[outputs] signals`` (all signals if none given)."""
    wanted = scenario.outputs.signals
    for name in wanted:
        if name not in result.signals:
            raise scenario.error(
                ("outputs", "signals"),
                f"result '{key}' has no signal '{name}'; available: {', '.join(result.names)}",
            )
    return result.select(list(wanted)) if wanted else result


def _plot_groups(scenario: Scenario, result: Result) -> dict[str, tuple[str, ...]]:
    """``[outputs.plots]`` checked against ``result``, or the signals grouped by unit."""
    if not scenario.outputs.plots:
        return groups_by_unit(result, result.names)
    for group, names in scenario.outputs.plots.items():
        path = ("outputs", "plots", group)
        missing = [n for n in names if n not in result.signals]
        if missing or not names:
            raise scenario.error(
                path, f"unknown signals {missing}; available: {', '.join(result.names)}"
            )
        units = {result.units[n] for n in names}
        if len(units) > 1:
            raise scenario.error(path, f"signals of one figure must share a unit, got {units}")
    return dict(scenario.outputs.plots)


def evaluate_checks(scenario: Scenario, metrics: dict[str, float]) -> dict[str, dict]:
    """Compare metrics with the ``[metrics]`` references.

    Returns
    -------
    dict
        Metric name -> ``{"value", "reference", "rtol", "atol", "ok", "source"}``.

    Raises
    ------
    ScenarioError
        A reference names a metric the run did not compute.
    """
    checks = {}
    for check in scenario.metrics:
        if check.name not in metrics:
            raise scenario.error(
                ("metrics", check.name),
                f"no such metric; this run computes {', '.join(metrics) or 'none'}",
            )
        value = metrics[check.name]
        checks[check.name] = {
            "value": value,
            "reference": check.reference,
            "rtol": check.rtol,
            "atol": check.atol,
            "ok": check.passes(value),
            "source": check.source,
        }
    return checks


#: Output points of a run above which it is announced before it starts (with its size).
LARGE_POINTS = 100_000

#: Wall time per output point and signal, s: simulation output, CSV and plots of
#: step-50g at a 20 us grid (100 001 points x 18 columns) on a 2-core machine.
SECONDS_PER_VALUE = 2e-6


def size_warning(sc: Scenario) -> str | None:
    """A one-line warning when ``sc`` asks for more than :data:`LARGE_POINTS` output
    points: their number, and the CSV size and wall time per signal it will take."""
    sim = sc.simulation
    if sim is None or not sim.output_interval:
        return None
    points = math.floor((sim.stop_time - sim.start_time) / sim.output_interval) + 1
    if points <= LARGE_POINTS:
        return None
    return (
        f"warning: {sc.name} keeps {points} output points ([simulation] output_interval = "
        f"{sim.output_interval:.3g} s over {sim.stop_time - sim.start_time:.3g} s): per signal "
        f"kept, about {points * CSV_BYTES_PER_VALUE / 1e6:.0f} MB of CSV and "
        f"{points * SECONDS_PER_VALUE:.1f} s; a coarser output_interval (default: 500 "
        "points) makes it smaller"
    )


def format_summary(output: RunOutput, checks: dict, out_dir: Path, files: list[Path]) -> str:
    """A short human summary: header line, metric table with references, files written."""
    head = (
        f"{output.scenario}: fidelity {output.fidelity}, solver {output.solver}, "
        f"{output.wall_time_s * 1e3:.1f} ms"
    )
    width = max([len("metric"), *map(len, output.metrics)])
    rows = [f"  {'metric':<{width}}  {'value':>12}  {'reference':>12}  check"]
    for name, value in output.metrics.items():
        check = checks.get(name)
        ref = f"{check['reference']:>12.6g}" if check else " " * 12
        verdict = ("ok" if check["ok"] else "OFF") if check else ""
        rows.append(f"  {name:<{width}}  {value:>12.6g}  {ref}  {verdict}".rstrip())
    why = output.extra.get("status_reason", {})
    for key, status in output.extra.get("status", {}).items():  # closed loops: by run
        rows.append(f"  {key + '_status':<{width}}  {status:>12}  {why.get(key, '')}".rstrip())
    names = ", ".join(p.name for p in files)
    return "\n".join([head, *rows, f"wrote {out_dir}: {names}"])


def run(
    scenario: str | Path | Scenario, out_dir: str | Path | None = None, *, quiet: bool = False
) -> RunOutput:
    """Run a scenario and write its outputs.

    Parameters
    ----------
    scenario : str, pathlib.Path or Scenario
        A scenario file, the name of a packaged scenario (``"paper-static"``), or a
        loaded :class:`~sarcomere.scenarios.spec.Scenario`.
    out_dir : str or pathlib.Path, optional
        Output folder; default ``out/<scenario name>``. It is checked before anything is
        computed (see :func:`~sarcomere.scenarios.outdir.check_out_dir`), and replaced
        whole only when the run succeeds: it holds all of one run or is left untouched.
    quiet : bool
        Do not print the summary, the warning before a run of more than
        :data:`LARGE_POINTS` output points, nor the progress line a run longer than 2 s
        shows on a terminal's stderr.

    Returns
    -------
    RunOutput
        With ``wall_time_s`` set (the kind runner alone, not the file writing).

    Raises
    ------
    ScenarioError
        Malformed scenario, unknown kind, or outputs asking for signals the run lacks.
    ParameterError
        ``out_dir`` cannot hold the results (a file, under a file, not writable...).
    SolverError
        The run failed or produced a NaN (naming the signal). A simulation that failed
        after some output points (its ``partial`` Result) is written first, with
        ``"status": "incomplete"`` and the ``reason`` in ``summary.json``.

    Examples
    --------
    >>> out = run("paper-static", tmp_path, quiet=True)  # doctest: +SKIP
    >>> sorted(out.metrics)[:2]  # doctest: +SKIP
    ['force_0p1MPa_N', 'force_spa_0p1MPa_N']
    """
    out = None if out_dir is None else check_out_dir(out_dir)  # before reading a long table
    if isinstance(scenario, Scenario):
        sc = scenario
    else:  # a long input table takes a while to read: the progress line covers it too
        with progress(f"loading {scenario}", enabled=not quiet):
            sc = load_scenario(scenario)
    runner = _runner(sc)
    out = check_out_dir(Path("out") / sc.name) if out is None else out
    if not quiet and (warning := size_warning(sc)):
        print(warning, file=sys.stderr)
    failure = None
    with staged(out) as tmp, progress(f"running {sc.name}", enabled=not quiet):
        start = time.perf_counter()
        try:
            output = runner(sc, tmp)
        except ParameterError as exc:  # a [solver] setting the method refuses: at its key
            if not (isinstance(exc.name, str) and exc.name.startswith("solver.")):
                raise
            raise sc.error(tuple(exc.name.split(".")), describe(exc)) from None
        except SolverError as exc:  # write what was computed, marked incomplete
            if not isinstance(exc.partial, Result):
                raise
            failure = exc
            output = RunOutput(
                sc.name,
                sc.model.fidelity,
                str(exc.partial.meta.get("method", "")),
                results={"main": exc.partial},
                incomplete=str(exc),
            )
        output.wall_time_s = time.perf_counter() - start
        check_finite(output)
        checks = {} if failure else evaluate_checks(sc, output.metrics)
        results = {key: _selected(sc, key, r) for key, r in output.results.items()}
        report("writing CSV")
        files = write_timeseries(results, tmp)
        if results:
            report("plotting")
            groups = _plot_groups(sc, next(iter(results.values())))
            files += plot_groups(results, groups, tmp, sc.name)
        extra = sorted(p for p in tmp.iterdir() if p not in files)  # the runner's own files
        files = [*files, *extra]
        files.insert(0, write_summary(output, sc, tmp, files, checks))
    if failure is not None:
        raise failure
    if not quiet:
        print(format_summary(output, checks, out, files))
    return output
