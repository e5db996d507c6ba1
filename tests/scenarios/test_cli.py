"""The runner and the ``sarcomere`` command line, end to end on the packaged scenario."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
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


def test_run_paper_static_writes_summary_csv_and_plots(tmp_path: Path, capsys) -> None:
    assert main(["run", "paper-static", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "theta_rest_deg" in printed and "summary.json" in printed

    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in ("scenario", "fidelity", "solver", "wall_time_s", "metrics", "sarcomere_version"):
        assert key in summary
    assert (summary["scenario"], summary["fidelity"]) == ("paper-static", "paper")
    assert summary["wall_time_s"] > 0
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
    assert (tmp_path / "plot_force.png").stat().st_size > 1000


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
    out = run(path, tmp_path / "o", quiet=True)
    assert out.wall_time_s > 0
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
