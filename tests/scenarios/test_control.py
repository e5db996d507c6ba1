"""Kind "closed_loop": the packaged control scenes, shortened, end to end; bad [control]."""

import json
import re

import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import load_scenario, parse_scenario, resolve_scenario, run

SUFFIXES = (
    "overshoot_pct",
    "settling_time_s",
    "constraint_violation_max",
    "solve_time_median_ms",
    "solve_time_p95_ms",
)


def _text(name: str) -> str:
    return resolve_scenario(name).read_text(encoding="utf-8")


def _short_length_scene() -> str:
    """control-length in 1.6 s: the step at 0.2 s, one 3 Hz period, +50 g at 1.3 s."""
    text = _text("control-length")
    text = text.replace('stop_time = "12.5 s"', 'stop_time = "1.6 s"')
    text = text.replace('step_time = "0.5 s"', 'step_time = "0.2 s"')
    text = re.sub(r"sines = \[.*?\]\n", "", text, flags=re.S)
    text = text.replace(
        'sine_amplitude = "1 mm"',
        'sine_amplitude = "1 mm"\nsines = [{ frequency = "3 Hz", start = "0.9 s", periods = 1 }]',
    )
    return text.replace('time = "6.25 s"', 'time = "1.3 s"')


def test_packaged_scenes_load():
    for name in ("control-length", "control-force"):
        sc = load_scenario(name)
        assert sc.kind == "closed_loop"
        assert set(sc.control["controllers"]) == {"pid", "lqi", "lqi_ekf"}


def test_length_scene_shortened_end_to_end(tmp_path):
    sc = parse_scenario(_short_length_scene(), "control-length-short.toml")
    out = run(sc, tmp_path, quiet=True)
    m = out.metrics
    for key in ("pid", "lqi", "lqi_ekf"):
        assert m[f"{key}_rmse_mm"] > 0
        for suffix in SUFFIXES:
            assert f"{key}_{suffix}" in m
        assert m[f"{key}_constraint_violation_max"] == 0  # the threads stay taut
        assert m[f"{key}_settling_time_s"] < 0.7  # a 1.5 mm step settles
        assert 0 < m[f"{key}_rmse_sine_3Hz_mm"] < 1.0
        assert m[f"{key}_disturbance_peak_mm"] > 3  # +50 g pulls the chain down
        assert m[f"{key}_fallbacks"] == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["metrics"]["pid_rmse_mm"] == pytest.approx(m["pid_rmse_mm"])
    for f in ("plot_length.png", "plot_pressure.png", "plot_tension.png", "timeseries_lqi.csv"):
        assert (tmp_path / f).stat().st_size > 1000
    header = (tmp_path / "timeseries_pid.csv").read_text().splitlines()[0]
    for column in ("reference [m]", "myofibril.length [m]", "regulator.p_cmd [Pa]", ".T [N]"):
        assert column in header


def test_force_scene_shortened(tmp_path):
    text = _text("control-force").replace('stop_time = "11.5 s"', 'stop_time = "1.2 s"')
    text = re.sub(
        r"\[control.controllers.lqi_ekf\]\ntype = \"lqi\"\nestimator = \"ekf\"\n", "", text
    )
    out = run(parse_scenario(text, "control-force-short.toml"), tmp_path, quiet=True)
    m = out.metrics
    assert m["pid_rmse_N"] > 0 and m["lqi_rmse_N"] > 0
    assert m["lqi_settling_time_s"] < 0.5
    assert "pid_disturbance_peak_N" not in m  # no disturbance in the force scene


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ('sample_time = "10 ms"', 'sample_tme = "10 ms"', "control.sample_tme"),
        ("[control.controllers.pid]", '[control.controllers.pid]\ntype = "pdi"', "pid.type"),
        ("[control.controllers.pid]", "[control.controllers.pid]\nkq = 1.0", "pid.kq"),
        ('pressure_max = "0.3 MPa"', 'pressure_max = "0.01 MPa"', "control.pressure_max"),
        ('output = "myofibril.length"', 'output = "myofibril.lenght"', "control.output"),
    ],
)
def test_bad_control_settings_are_refused_by_key(tmp_path, old, new, key):
    text = _short_length_scene().replace(old, new)
    with pytest.raises(ScenarioError, match=re.escape(key.split(".")[-1])):
        run(parse_scenario(text, "bad.toml"), tmp_path / "out", quiet=True)


def test_other_kinds_refuse_a_control_section(tmp_path):
    text = _text("step-50g") + '\n[control]\noutput = "myofibril.length"\n'
    with pytest.raises(ScenarioError, match=r"does not use \[control\]"):
        run(parse_scenario(text, "x.toml"), tmp_path / "out", quiet=True)
