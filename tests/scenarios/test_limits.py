"""Limits are checked at once, with the numbers; long runs show progress on a terminal."""

import io
import sys
import time
import types

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, run
from sarcomere.scenarios.progress import progress

SCENE = """
[scenario]
kind = "transient"
[model]
fidelity = "{fid}"
n = {n}
[inputs.pressure]
type = "step"
final = "0.1 MPa"
[simulation]
stop_time = "{stop}"
output_interval = "{dt}"
{extra}
"""


def _scene(fid="symmetric", n=1, stop="1000 s", dt="0.1 ms", extra=""):
    return parse_scenario(SCENE.format(fid=fid, n=n, stop=stop, dt=dt, extra=extra), "l.toml")


def test_an_oversized_output_is_refused_before_running(tmp_path):
    tic = time.perf_counter()
    with pytest.raises(ScenarioError) as info:
        run(_scene(), tmp_path, quiet=True)
    assert time.perf_counter() - tic < 5
    msg = str(info.value)
    assert "simulation.output_interval" in msg and "up to 10000002 points x" in msg
    assert "MB of CSV" in msg and "max_values = 2e+07" in msg


def test_max_values_is_configurable(tmp_path):
    with pytest.raises(ScenarioError, match=r"max_values = 100"):
        run(_scene(stop="1 s", dt="1 ms", extra="[outputs]\nmax_values = 100"), tmp_path)


@pytest.mark.parametrize(
    ("fid", "n", "limit"),
    [("full", 176, 175), ("auto", 1000, 175), ("symmetric", 10000, 2000)],
)
def test_n_above_the_measured_limit_is_refused_at_once(tmp_path, fid, n, limit):
    extra = '[outputs]\ntolerance = "1 %"' if fid == "auto" else ""
    tic = time.perf_counter()
    with pytest.raises(ScenarioError, match=rf"model.n.*n = {n} is above {limit}"):
        run(_scene(fid, n, "1 s", "10 ms", extra), tmp_path, quiet=True)
    assert time.perf_counter() - tic < 2


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_shows_on_a_terminal_after_the_delay():
    out = _Terminal()
    with progress("running x", stream=out, delay=0.05, every=0.05):
        time.sleep(0.3)
    text = out.getvalue()
    assert "\rrunning x: 0 s" in text and text.endswith("s\n") and "done in" in text


def test_progress_is_silent_when_quick_quiet_or_not_a_terminal():
    for stream, enabled, nap in ((_Terminal(), True, 0.0), (_Terminal(), False, 0.2)):
        with progress("x", stream=stream, enabled=enabled, delay=0.05, every=0.05):
            time.sleep(nap)
        assert stream.getvalue() == ""
    pipe = io.StringIO()
    with progress("x", stream=pipe, delay=0.0, every=0.05):
        time.sleep(0.1)
    assert pipe.getvalue() == ""


def test_bench_shows_progress_on_a_terminal(tmp_path, monkeypatch, capsys):
    from sarcomere.scenarios import bench
    from sarcomere.scenarios.cli import main

    def study(out_dir, quick=False):
        time.sleep(0.3)
        return {"metrics": {}, "files": []}

    fake = types.ModuleType("fake_study")
    fake.study = study
    monkeypatch.setitem(sys.modules, "fake_study", fake)
    monkeypatch.setitem(bench.STUDIES, "stability", ("fake_study", "test"))
    monkeypatch.setattr("sarcomere.scenarios.progress.DELAY_S", 0.05)
    terminal = _Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    assert main(["bench", "stability", "--out", str(tmp_path / "b")]) == 0
    assert "bench stability: 0 s" in terminal.getvalue()


P_MAX_SCENE = """
[scenario]
kind = "transient"
[model]
n = 1
[model.options]
load = "50 g"
[parameters]
"regulator.p_max" = "1 MPa"
[inputs.pressure]
type = "step"
final = "{final}"
time = "0.1 s"
[simulation]
stop_time = "0.5 s"
output_interval = "5 ms"
"""


def test_raising_p_max_moves_the_pressure_range(tmp_path):
    """Issue 16 bug 2: with a 1 MPa regulator a 0.65 MPa step runs (it was refused as
    outside [0, 0.6] MPa) and the regulator follows it unclamped: its first-order lag
    p_out = P (1 - exp(-(t - 0.1 s) / 50 ms)); 1.2 MPa is refused against [0, 1] MPa."""
    out = run(parse_scenario(P_MAX_SCENE.format(final="0.65 MPa"), "p.toml"), tmp_path / "a")
    res = out.results["main"]
    t = res.index
    expected = np.where(t > 0.1, 6.5e5 * (1 - np.exp(-(t - 0.1) / 0.05)), 0.0)
    assert np.max(np.abs(res["regulator.p_out"] - expected)) < 1e-3 * 6.5e5
    with pytest.raises(ScenarioError, match=r"1\.2 MPa at t = 0\.1 s is outside .* \[0, 1\] MPa"):
        run(parse_scenario(P_MAX_SCENE.format(final="1.2 MPa"), "p.toml"), tmp_path / "b")


def test_a_command_just_above_the_range_shows_the_digits_that_differ(tmp_path):
    text = P_MAX_SCENE.format(final="0.6000001 MPa").replace('"regulator.p_max" = "1 MPa"', "")
    with pytest.raises(ScenarioError, match=r"0\.6000001 MPa at t = 0\.1 s is outside"):
        run(parse_scenario(text, "p.toml"), tmp_path)


def test_linearize_names_pressure_outside_the_range(tmp_path, capsys):
    from sarcomere.scenarios.cli import main

    assert main(["linearize", "step-50g", "--pressure", "0.8 MPa", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "key '--pressure': 0.8 MPa is outside the regulator's range [0, 0.6] MPa" in err


@pytest.mark.parametrize(
    ("value", "needle"),
    [
        ("nan", "nan is not a whole number"),
        ("inf", "inf is not a whole number"),
        ("-inf", "-inf is not a whole number"),
        ("2.5", "2.5 is not a whole number"),
        ("0", "0 is outside [1, 1e+09]"),
        ("2e9", "2e+09 is outside [1, 1e+09]"),
        ('"big"', "'big' is not a whole number"),
    ],
)
def test_max_values_is_a_finite_whole_number_in_range(value, needle):
    """Issue 16 bug 5: nan disabled the size guard (a 3.64 TiB allocation), inf too."""
    with pytest.raises(ScenarioError, match=r"l\.toml:\d+: key 'outputs\.max_values'") as info:
        _scene(stop="1 s", dt="1e-12 s", extra=f"[outputs]\nmax_values = {value}")
    assert needle in str(info.value)
