"""The runner and the ``sarcomere`` command line, end to end on the packaged scenario."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.results import Result
from sarcomere.scenarios import RunOutput, register_runner, run
from sarcomere.scenarios.cli import main
from sarcomere.scenarios.output import check_finite

PAPER_METRICS = {
    "theta_rest_deg": 51.32,
    "h_m_mm": 28.0,
    "rest_length_n3_mm": 165.0,
    "force_spa_0p1MPa_N": 0.315,
    "table1_force_ecoflex_00_30_N": 0.0416,
    "table1_force_elastosil_m4601_N": 0.2968,
    "table1_force_smooth_sil_950_N": 0.7191,
}


def test_run_paper_static_writes_summary_csv_and_plots(tmp_path: Path, capsys, drawn_png) -> None:
    started = time.perf_counter()
    assert main(["run", "paper-static", "--out", str(tmp_path)]) == 0
    elapsed = time.perf_counter() - started
    printed = capsys.readouterr().out
    assert "theta_rest_deg" in printed and "summary.json" in printed

    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in ("scenario", "fidelity", "solver", "wall_time_s", "metrics", "sarcomere_version"):
        assert key in summary
    assert (summary["scenario"], summary["fidelity"]) == ("paper-static", "paper")
    assert 0 < summary["wall_time_s"] <= elapsed  # measured inside this call
    metrics = summary["metrics"]
    assert "force_0p1MPa_N" in metrics
    for name, reference in PAPER_METRICS.items():
        assert metrics[name] == pytest.approx(reference, rel=0.025), name
    assert all(c["ok"] for n, c in summary["checks"].items() if n != "force_0p1MPa_N")

    with open(tmp_path / "timeseries.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0][:3] == ["pressure [Pa]", "F_spa [N]", "F_contr [N]"]
    assert "theta [rad]" in rows[0] and "lambda_jz [1]" in rows[0]
    pressures = [float(r[0]) for r in rows[1:]]
    assert pressures[0] == pytest.approx(1e4) and pressures[-1] == pytest.approx(1e5)
    assert {round(p) for p in pressures} >= {k * 10_000 for k in range(1, 11)}
    drawn_png(tmp_path / "plot_force.png")


def test_list_shows_packaged_scenarios(capsys) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "paper-static" in out and "static" in out


def test_malformed_scenario_exits_2_with_one_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[scenario]\nkind = "static"\n[model]\nfidelty = "paper"\n')
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert f"{bad}:4" in err and "did you mean 'fidelity'" in err


def test_runner_errors_carry_the_scenario_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[scenario]\nkind = "static"\n[model]\nfidelity = "paper"\n'
        '[model.options]\ntheta = "bent"\n[sweep.pressure]\nvalues = ["10 kPa"]\n'
    )
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:6" in err and "model.options.theta" in err


def test_unknown_kind(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "k.toml"
    bad.write_text('[scenario]\nkind = "nope"\n')
    assert main(["run", str(bad)]) == 2
    assert "unknown kind 'nope'" in capsys.readouterr().err


def _two_curves(scenario, out_dir: Path) -> RunOutput:
    t = np.linspace(0.0, 1.0, 5)
    results = {
        f"load_{m}g": Result("time", "s", t, {"x": m * t, "p": 1e5 + 0 * t}, {"x": "m", "p": "Pa"})
        for m in (0, 50)
    }
    return RunOutput(scenario.name, "full", "test", metrics={"x_end_m": 50.0}, results=results)


def test_registered_kind_with_several_results(tmp_path: Path) -> None:
    register_runner("two-curves", _two_curves, replace=True)
    path = tmp_path / "two.toml"
    path.write_text('[scenario]\nkind = "two-curves"\n[outputs]\nsignals = ["x"]\n')
    started = time.perf_counter()
    out = run(path, tmp_path / "o", quiet=True)
    assert 0 < out.wall_time_s <= time.perf_counter() - started
    header = (tmp_path / "o" / "timeseries_load_50g.csv").read_text().splitlines()[0]
    assert header == "time [s],x [m]"
    assert (tmp_path / "o" / "timeseries_load_0g.csv").exists()
    assert (tmp_path / "o" / "plot_length.png").exists()
    with pytest.raises(ValueError, match="already has runner"):
        register_runner("two-curves", lambda s, o: _two_curves(s, o))


def test_nan_is_never_silent() -> None:
    t = np.array([0.0, 1.0, 2.0])
    result = Result("time", "s", t, {"load.s": np.array([0.0, math.nan, 1.0])}, {"load.s": "m"})
    with pytest.raises(SolverError, match="'load.s'") as info:
        check_finite(RunOutput("x", "full", "idas", results={"main": result}))
    assert info.value.time == 1.0
    with pytest.raises(SolverError, match="metric 'f_N'"):
        check_finite(RunOutput("x", "full", "idas", metrics={"f_N": math.nan}))


def test_console_script_help() -> None:
    # the script installed beside this interpreter (a venv's bin/), not whatever is on PATH
    script = Path(sys.executable).parent / "sarcomere"
    assert script.exists(), f"console script not installed beside {sys.executable}"
    done = subprocess.run([str(script), "--help"], capture_output=True, text=True, check=True)
    assert "run" in done.stdout and "list" in done.stdout


HEAVY = ("casadi", "control", "matplotlib", "scipy.signal", "pint", "sarcomere.scenarios.binding")

_PROBE = f"""
import json, sys
from sarcomere.scenarios.cli import main
HEAVY = {HEAVY!r}
try:
    status = main(sys.argv[1:])
except SystemExit as exc:
    status = exc.code
print(json.dumps(dict(status=status, heavy=sorted(m for m in HEAVY if m in sys.modules))))
"""


@pytest.mark.parametrize(
    ("argv", "status"),
    [
        (["--version"], 0),
        (["--help"], 0),
        (["list"], 0),
        ([], 2),  # no command
        (["nosuch"], 2),
        (["run"], 2),  # no scenario
        (["run", "step-50g", "--bogus"], 2),
        (["bench", "nosuch", "--out", "x"], 2),
        (["linearize", "--help"], 0),
        (["calibrate", "--bogus"], 2),
        (["calibrate", "--help"], 0),
        (["export-fmu", "step-50g", "--bogus"], 2),
        (["export-fmu", "--help"], 0),
    ],
)
def test_the_cli_answers_without_importing_the_model_library(argv, status) -> None:
    """--version, --help, list and argument errors start at once: no CasADi, no
    python-control, no matplotlib, no pint (BENCHMARKS.md, start-up section)."""
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, *argv], capture_output=True, text=True, check=True
    )
    probe = json.loads(done.stdout.splitlines()[-1])
    assert probe == {"status": status, "heavy": []}, done.stderr


def test_list_matches_the_loaded_scenarios(capsys) -> None:
    """``list`` reads each file's [scenario] table without loading the model: the kinds and
    descriptions it shows are the loaded scenarios' own."""
    from sarcomere.scenarios import load_scenario, packaged_scenarios

    assert main(["list"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert len(rows) == len(packaged_scenarios())
    for row, name in zip(rows, packaged_scenarios(), strict=True):
        sc = load_scenario(name)
        assert row.split()[:2] == [name, sc.kind] and row.endswith(sc.description)


@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_a_transient_run_imports_neither_python_control_nor_pyplot_nor_pint(tmp_path: Path) -> None:
    code = (
        "import sys; from sarcomere.scenarios.cli import main;"
        f"s = main(['run', 'step-50g', '--quiet', '--out', {str(tmp_path / 'o')!r}]);"
        "print(s, sorted(m for m in ('control', 'matplotlib.pyplot', 'scipy.signal', 'pint',"
        " 'sarcomere.scenarios.cosim', 'sarcomere.controllers') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split("\n")[-2] == "0 []", done.stderr
    assert (tmp_path / "o" / "plot_length.png").is_file()


def test_the_packages_lazy_names_all_resolve() -> None:
    import sarcomere.dynamics as dynamics
    import sarcomere.scenarios as scenarios

    for package in (dynamics, scenarios):
        for name in package.__all__:
            assert getattr(package, name) is not None, name
        with pytest.raises(AttributeError, match="no attribute 'nope'"):
            package.nope  # noqa: B018


def test_the_csv_holds_every_value_exactly_across_chunks(tmp_path: Path) -> None:
    from sarcomere.scenarios.output import CSV_CHUNK_ROWS, write_timeseries

    rng = np.random.default_rng(1)
    n = 2 * CSV_CHUNK_ROWS + 7
    t = np.sort(rng.uniform(0.0, 2.0, n))
    signals = {"a": rng.normal(size=n) * 1e5, "b": rng.normal(size=n) * 1e-9}
    result = Result("time", "s", t, signals, {"a": "Pa", "b": "m"})
    (path,) = write_timeseries({"main": result}, tmp_path)
    with open(path) as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["time [s]", "a [Pa]", "b [m]"]
    table = np.array(rows[1:], dtype=float)
    assert table.shape == (n, 3)
    assert np.array_equal(table, np.column_stack([t, signals["a"], signals["b"]]))


def test_a_large_run_is_announced_before_it_starts(tmp_path: Path, capsys, monkeypatch) -> None:
    """A 500 k-point run gave no warning and took minutes: it says its size first."""
    from sarcomere.scenarios import load_scenario, packaged_scenarios, parse_scenario
    from sarcomere.scenarios.output import CSV_BYTES_PER_VALUE
    from sarcomere.scenarios.runner import size_warning

    assert size_warning(load_scenario("step-50g")) is None  # 1001 points: silent
    text = packaged_scenarios()["step-50g"].read_text()
    text = text.replace('output_interval = "2 ms"', 'output_interval = "4 us"')
    seen = []

    def runner(sc, out):
        seen.append(capsys.readouterr().err)  # printed before the run starts
        return RunOutput(sc.name, "full", "none")

    monkeypatch.setattr("sarcomere.scenarios.runner._RUNNERS", {"transient": runner})
    run(parse_scenario(text, "big.toml"), tmp_path / "o")
    points = 500_001
    assert seen[0].startswith(f"warning: step-50g keeps {points} output points")
    assert f"about {points * CSV_BYTES_PER_VALUE / 1e6:.0f} MB of CSV" in seen[0]


def test_an_interrupted_progress_line_is_cleared_not_called_done() -> None:
    import io
    import time

    from sarcomere.scenarios.progress import progress

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Terminal()
    with pytest.raises(KeyboardInterrupt), progress("running x", stream=out, delay=0.0):
        time.sleep(0.2)
        raise KeyboardInterrupt
    text = out.getvalue()
    assert "running x: 0 s" in text and "done" not in text and text.endswith("\r")


def test_a_closed_pipe_ends_the_output_quietly() -> None:
    """``sarcomere list | head -1`` printed a BrokenPipeError traceback."""
    script = Path(sys.executable).parent / "sarcomere"
    read, write = os.pipe()
    os.close(read)  # the reader is gone before anything is written
    try:
        done = subprocess.run(
            [str(script), "list"], stdout=write, stderr=subprocess.PIPE, text=True, check=False
        )
    finally:
        os.close(write)
    assert (done.returncode, done.stderr) == (141, "")


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        # a bare number was taken as Pa: 100 Pa where 100 kPa was meant (issue 24)
        (["--pressure", "100"], "'--pressure' = '100' is invalid (a bare number needs a unit"),
        # a negative quantity was an argparse error ("expected one argument")
        (["--pressure", "-1MPa"], "key '--pressure': -1 MPa is outside the regulator's range"),
        (["--pressure", "-.5 MPa"], "key '--pressure': -0.5 MPa is outside the regulator's"),
        # was "parameter 'outputs' = ...": the option is --output
        (["--output", "myofibril.lenght"], "key '--output': 'myofibril.lenght' is not a signal"),
    ],
)
def test_linearize_options_are_refused_by_their_own_name(tmp_path, capsys, args, needle):
    out = tmp_path / "lin"
    assert main(["linearize", "step-50g", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err, err
    assert not out.exists()


def test_a_negative_value_of_an_option_reaches_the_option() -> None:
    from sarcomere.scenarios.cli import _signed_values

    argv = ["linearize", "x", "--pressure", "-1MPa", "--out", "-2", "--", "-3kPa"]
    assert _signed_values(argv) == [
        "linearize",
        "x",
        "--pressure=-1MPa",
        "--out=-2",
        "--",
        "-3kPa",
    ]
    assert _signed_values(["run", "--quiet", "x.toml"]) == ["run", "--quiet", "x.toml"]


def test_bench_says_why_a_metric_is_missing(tmp_path, monkeypatch, capsys) -> None:
    """``bench mpc`` printed ``nmpc_speedup_vs_do_mpc = None`` without saying that do-mpc
    is not installed."""
    import types

    from sarcomere.scenarios import bench
    from sarcomere.scenarios.studies import mpc_speed

    monkeypatch.setitem(sys.modules, "do_mpc", None)  # not importable
    why = mpc_speed._do_mpc_status()
    assert why == 'do-mpc not installed: pip install "sarcomere[bench]"'

    def study(out_dir, quick=False):
        return {"metrics": {"a_ms": 1.5, "b_ratio": None}, "files": [], "notes": {"b_ratio": why}}

    fake = types.ModuleType("fake_study")
    fake.study = study
    monkeypatch.setitem(sys.modules, "fake_study", fake)
    monkeypatch.setitem(bench.STUDIES, "mpc", ("fake_study", "test"))
    assert main(["bench", "mpc", "--out", str(tmp_path / "b")]) == 0
    printed = capsys.readouterr().out
    assert "  a_ms = 1.5\n" in printed
    assert f"  b_ratio = None ({why})\n" in printed


def test_linearize_takes_an_auto_scene_at_full(tmp_path, capsys) -> None:
    """``linearize step-50g-auto`` was refused: 'auto' is not one of the levels."""
    out = tmp_path / "lin"
    assert main(["linearize", "step-50g-auto", "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["fidelity"] == "full"
    assert "load (load.s)" in capsys.readouterr().out


@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
@pytest.mark.parametrize(
    "argv",
    [
        ["run", "step-50g", "--quiet"],
        ["run", "vent-0g", "--quiet"],
        ["linearize", "control-length"],
        ["calibrate"],
    ],
)
def test_a_cli_run_raises_no_numpy_warning(tmp_path, capsys, argv) -> None:
    """Issue 24 saw numpy warnings on the console: a run, a linearisation and the
    calibration give none (every packaged scene and bench --quick were checked by hand)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert main([*argv, "--out", str(tmp_path / "o")]) == 0
    assert "Warning" not in capsys.readouterr().err
