"""Kind "pwm_hold": the PWM valve against the regulator holding a length (issue 26)."""

import re
from importlib import resources

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import load_scenario, parse_scenario, run


def _text() -> str:
    return resources.files("sarcomere.scenarios").joinpath("pwm-hold.toml").read_text()


def _short() -> str:
    """The packaged scene shortened: 0.6 s, +20 g at 0.3 s, 50 Hz only, no NMPC."""
    text = _text().replace('stop_time = "2 s"', 'stop_time = "0.6 s"')
    text = text.replace('frequencies = ["20 Hz", "50 Hz", "100 Hz"]', 'frequencies = ["50 Hz"]')
    text = text.replace('nmpc_frequency = "50 Hz"', 'nmpc_frequency = "0 Hz"')
    return text.replace('time = "1 s"', 'time = "0.3 s"')


def test_packaged_scene_loads():
    sc = load_scenario("pwm-hold")
    assert sc.kind == "pwm_hold" and sc.control["frequencies"] == ["20 Hz", "50 Hz", "100 Hz"]


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ('frequencies = ["20 Hz", "50 Hz", "100 Hz"]', 'frequencies = ["10 Hz"]', "frequencies"),
        ("points_per_period = 20", "points_per_period = 1", "points_per_period"),
        ("points_per_period = 20", "points_per_period = 20\nwobble = 1", "wobble"),
        (
            'nmpc_frequency = "50 Hz"',
            'nmpc_frequency = "50 Hz"\naveraged_frequency = "30 Hz"',
            "averaged_frequency",
        ),
        (
            "[control.disturbance]",
            '[control.valve]\nlevel = "averaged"\n\n[control.disturbance]',
            "level",
        ),
        (
            "[control.disturbance]",
            '[control.valve]\nways = "5/2"\n\n[control.disturbance]',
            "valve",
        ),
    ],
)
def test_bad_settings_are_refused_by_key(tmp_path, old, new, key):
    text = _text().replace(old, new)
    assert text != _text()
    with pytest.raises(ScenarioError, match=re.escape(key)):
        run(parse_scenario(text, "bad.toml"), tmp_path / "out", quiet=True)


@pytest.mark.slow  # some 5 s of CPU
def test_shortened_scene_end_to_end(tmp_path):
    out = run(parse_scenario(_short(), "pwm-hold-short.toml"), tmp_path, quiet=True)
    m = out.metrics
    # the valve ripples the chamber by tens of kPa, the regulator by nothing
    assert m["pwm50_pi_ripple_pp_kPa"] > 1e3 * m["regulator_pi_ripple_pp_kPa"]
    assert m["pwm50_pi_ripple_pp_kPa"] > 10.0
    # the averaged valve has no ripple, and the 3/2 valve vents air every period
    assert m["pwm50_pi_averaged_ripple_pp_kPa"] < 0.01 * m["pwm50_pi_ripple_pp_kPa"]
    assert m["pwm50_pi_air_used_mg"] > 10 * m["regulator_pi_air_used_mg"]
    # the air used recomputed from the written flow (an independent path)
    res = out.results["pwm50_pi"]
    air = np.trapezoid(res["air_flow"], res.index) * 1e6
    assert air == pytest.approx(m["pwm50_pi_air_used_mg"], rel=1e-9)
    for key in ("regulator_pi", "pwm50_pi", "pwm50_pi_averaged"):
        assert m[f"{key}_rmse_mm"] < m[f"{key}_disturbance_peak_mm"]
    assert m["pwm50_averaged_cpu_ratio"] > 2.0  # 10-13x measured; load-proof margin
    assert out.extra["hold_duty"] == pytest.approx(0.41, abs=0.02)
