"""A results folder holds all of one run or is left untouched; bad folders are refused first."""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys

import pytest

from sarcomere.dynamics.errors import ParameterError, ScenarioError, SolverError
from sarcomere.scenarios import parse_scenario, run
from sarcomere.scenarios.cli import main

STATIC = """
[scenario]
name = "{name}"
kind = "static"
[model]
fidelity = "paper"
[sweep.pressure]
values = ["0.05 MPa", "0.1 MPa"]
"""


def _static(name: str = "s"):
    return parse_scenario(STATIC.format(name=name), "s.toml")


def test_a_failed_run_leaves_the_previous_results_whole(tmp_path, monkeypatch):
    out = tmp_path / "o"
    run(_static(), out, quiet=True)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken(*args, **kwargs):
        raise SolverError("disk on fire")

    monkeypatch.setattr("sarcomere.scenarios.runner.write_summary", broken)
    longer = STATIC.format(name="s").replace('"0.05 MPa", ', '"0.02 MPa", "0.05 MPa", ')
    with pytest.raises(SolverError):
        run(parse_scenario(longer, "s.toml"), out, quiet=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]  # no temporary left


def test_a_run_into_another_runs_folder_leaves_no_stale_file(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    old = {"scenario": "older", "files": ["timeseries_load_0g.csv", "plot_stretch.png"]}
    (out / "summary.json").write_text(json.dumps(old))
    (out / "timeseries_load_0g.csv").write_text("old")
    (out / "plot_stretch.png").write_text("old")
    run(_static(), out, quiet=True)
    summary = json.loads((out / "summary.json").read_text())
    assert sorted(p.name for p in out.iterdir()) == sorted([*summary["files"], "summary.json"])


def test_a_failed_run_leaves_no_empty_folder(tmp_path):
    bad = parse_scenario(STATIC.format(name="b").replace('"paper"', '"full"'), "b.toml")
    with pytest.raises(ScenarioError):
        run(bad, tmp_path / "new" / "deeper", quiet=True)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", [".", ".."])
def test_dot_names_are_refused(name):
    with pytest.raises(ScenarioError, match="scenario.name"):
        _static(name)


def _refused(tmp_path, capsys, out: str, why: str) -> None:
    path = tmp_path / "s.toml"
    path.write_text(STATIC.format(name="s"))
    assert main(["run", str(path), "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and why in err and "'--out'" in err, err


def test_out_empty_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _refused(tmp_path, capsys, "", "empty path")
    _refused(tmp_path, capsys, ".", "current folder")


def test_out_file_or_under_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    _refused(tmp_path, capsys, str(tmp_path / "f"), "existing file")
    _refused(tmp_path, capsys, str(tmp_path / "f" / "sub"), "is a file")


def test_out_holding_other_files_is_refused(tmp_path, capsys):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("x")
    _refused(tmp_path, capsys, str(tmp_path / "mine"), "no run wrote")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_out_unwritable_is_refused(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        _refused(tmp_path, capsys, str(ro / "x"), "not writable")
    finally:
        ro.chmod(0o700)


def test_out_is_checked_before_computing(tmp_path, monkeypatch):
    (tmp_path / "f").write_text("x")
    calls = []
    monkeypatch.setattr(
        "sarcomere.scenarios.runner._RUNNERS", {"static": lambda sc, o: calls.append(sc)}
    )
    with pytest.raises(ParameterError, match="existing file"):
        run(_static(), tmp_path / "f", quiet=True)
    assert calls == []


def test_calibrate_checks_out_before_fitting(tmp_path, capsys, monkeypatch):
    (tmp_path / "f").write_text("x")

    def fit(**kwargs):
        raise AssertionError("fitted before checking --out")

    monkeypatch.setattr("sarcomere.dynamics.calibration.calibrate", fit)
    assert main(["calibrate", "--out", str(tmp_path / "f")]) == 2
    assert "existing file" in capsys.readouterr().err


def test_bench_checks_out_before_running(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    assert main(["bench", "stability", "--quick", "--out", str(tmp_path / "f" / "x")]) == 2
    assert "is a file" in capsys.readouterr().err


def test_calibrate_family_failure_writes_nothing(tmp_path, capsys, monkeypatch):
    from sarcomere.dynamics import calibration as command  # the handler's imports

    class Fit:
        def to_dict(self) -> dict:
            return {"fitted": {}}

    def family_fails():
        raise SolverError("family did not converge")

    monkeypatch.setattr(command, "calibrate", lambda verbose=False: Fit())
    monkeypatch.setattr(command, "family", family_fails)
    assert main(["calibrate", "--family", "--out", str(tmp_path / "c")]) == 2
    assert "family did not converge" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no calibration.json without its family


@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_calibrate_family_writes_every_file_of_one_run(tmp_path, monkeypatch):
    """The CLI end to end on a two-member family (the full family takes a minute)."""
    from sarcomere.dynamics import calibration

    two = functools.partial(calibration.family, (8e-3, 20e-3))
    monkeypatch.setattr("sarcomere.dynamics.calibration.family", two)
    out = tmp_path / "cal"
    assert main(["calibrate", "--family", "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"calibration.json", "family.json", "family.csv", "concentric-family.png"}
    record = json.loads((out / "family.json").read_text())
    assert [r["L_r_m"] for r in record] == [8e-3, 20e-3]
    for r in record:  # every member meets the isometric target, yet they differ under load
        assert r["achieved"]["force_n1_0p1MPa_N"] == pytest.approx(0.315, rel=1e-6)
    assert record[0]["strain_0p1MPa"]["50 g"] != pytest.approx(record[1]["strain_0p1MPa"]["50 g"])
    rows = (out / "family.csv").read_text().splitlines()
    assert rows[0] == "L_r_m,load_kg,pressure_Pa,strain" and len(rows) == 1 + 2 * 5 * 11
    assert list(tmp_path.iterdir()) == [out]  # no staging folder left behind


@pytest.mark.parametrize(
    ("summary", "why"),
    [
        ("{}", "not a sarcomere run's"),
        ("[1, 2]", "not a sarcomere run's"),
        ("not json", "not a sarcomere run's"),
        ('{"scenario": "s", "files": []}', "files no run wrote: thesis.tex"),
    ],
)
def test_a_folder_is_replaced_only_when_wholly_a_runs(tmp_path, capsys, summary, why):
    """Any summary.json used to mark a folder replaceable, deleting the user's files in it."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "summary.json").write_text(summary)
    (mine / "thesis.tex").write_text("years of work")
    _refused(tmp_path, capsys, str(mine), why)
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_a_runs_own_folder_is_replaced(tmp_path):
    out = tmp_path / "o"
    run(_static(), out, quiet=True)
    run(_static(), out, quiet=True)  # its summary lists every file: replaceable
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ParameterError, match="notes.txt"):
        run(_static(), out, quiet=True)


def test_a_dangling_link_is_checked_first_and_its_target_written(tmp_path, monkeypatch):
    """Bug 6: a dangling --out link ran the whole scenario, then NotADirectoryError."""
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "target" / "deeper")
    assert main(["run", str(_file(tmp_path)), "--quiet", "--out", str(link)]) == 0
    assert link.is_symlink() and (link / "summary.json").is_file()
    assert (tmp_path / "target" / "deeper" / "summary.json").is_file()
    (tmp_path / "f").write_text("x")
    link.unlink()
    link.symlink_to(tmp_path / "f" / "sub")  # cannot become a folder: refused before running
    calls = []
    monkeypatch.setattr(
        "sarcomere.scenarios.runner._RUNNERS", {"static": lambda sc, o: calls.append(sc)}
    )
    with pytest.raises(ParameterError, match="is a file"):
        run(_static(), link, quiet=True)
    assert calls == []


def test_a_link_to_a_folder_is_written_through(tmp_path):
    """A symlinked --out was replaced by a real folder and its target left empty."""
    target = tmp_path / "target"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)
    run(_static(), link, quiet=True)
    assert link.is_symlink() and (target / "summary.json").is_file()
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    with pytest.raises(ParameterError, match="cannot be followed"):
        run(_static(), loop, quiet=True)


def test_results_folders_follow_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        run(_static(), tmp_path / "o", quiet=True)
    finally:
        os.umask(old)
    assert (tmp_path / "o").stat().st_mode & 0o777 == 0o750
    assert (tmp_path / "o" / "summary.json").stat().st_mode & 0o777 == 0o640


def _file(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(STATIC.format(name="s"))
    return path


SLOW_RUN = """
import signal, sys, time
from sarcomere.scenarios import register_runner
from sarcomere.scenarios.cli import main
signal.signal(signal.SIGINT, signal.default_int_handler)  # even if the parent ignores it
def slow(sc, out):
    (out / "partial.csv").write_text("half")
    print("started", flush=True)
    time.sleep(60)
register_runner("slow", slow)
sys.exit(main(["run", sys.argv[1], "--out", sys.argv[2]]))
"""


@pytest.mark.parametrize(("signum", "status", "word"), [(2, 130, "SIGINT"), (15, 143, "SIGTERM")])
@pytest.mark.slow  # end to end or compiles: the full suite (CI) runs it
def test_an_interrupted_run_says_one_line_and_leaves_nothing(tmp_path, signum, status, word):
    """Ctrl-C printed a 30-line traceback; SIGTERM left a hidden .o.*.tmp folder."""
    scene = tmp_path / "slow.toml"
    scene.write_text('[scenario]\nkind = "slow"\n')
    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_RUN, str(scene), str(tmp_path / "o")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline() == "started\n"
    assert len(list(tmp_path.glob(".o.*.tmp"))) == 1  # the run is staging its files
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status
    assert err.count("\n") == 1 and word in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["slow.toml"]


def test_out_is_checked_before_the_scenario_is_read(tmp_path, monkeypatch):
    """Reading a scenario can take long (a long input table): a bad out_dir comes first."""
    (tmp_path / "f").write_text("x")

    def load(source):
        raise AssertionError("read the scenario before checking out_dir")

    monkeypatch.setattr("sarcomere.scenarios.runner.load_scenario", load)
    with pytest.raises(ParameterError, match="existing file"):
        run(str(_file(tmp_path)), tmp_path / "f", quiet=True)
