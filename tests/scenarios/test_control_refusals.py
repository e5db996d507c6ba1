"""Closed-loop scenes that cannot be run as written are refused by key, in one line
(issue 24: each of these was a traceback, a blow-up or a silent wrong number)."""

import re

import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, resolve_scenario, run


def _short() -> str:
    """control-length in 1.6 s without sines: the step at 0.2 s, +50 g at 1.3 s, PID only."""
    text = resolve_scenario("control-length").read_text(encoding="utf-8")
    text = text.replace('stop_time = "12.5 s"', 'stop_time = "1.6 s"')
    text = text.replace('step_time = "0.5 s"', 'step_time = "0.2 s"')
    text = re.sub(r"sines = \[.*?\]\n", "", text, flags=re.S)
    text = text.replace('time = "6.25 s"', 'time = "1.3 s"')
    return re.sub(r"\[control\.controllers\.(?!pid\])\w+\]\n(\w.*\n)*", "", text)


SINE = 'sine_amplitude = "1 mm"\nsines = [{ frequency = "3 Hz", start = "%s", periods = 1 }]'


@pytest.mark.parametrize(
    ("old", "new", "key", "words"),
    [
        # bug 6: -50 g on 20 g, a negative mass (CVODES blew up, the body at 45 km)
        ('load = "50 g"', 'load = "-50 g"', "control.disturbance.load", "load.m"),
        # bug 7: a disturbance after the end (ValueError traceback in disturbance_peak)
        ('time = "1.3 s"', 'time = "2 s"', "control.disturbance.time", "[0, 1.6) s"),
        # bug 8: a setting of the wrong type (TypeError traceback in make_pid)
        (
            "[control.controllers.pid]",
            '[control.controllers.pid]\nkp = "fast"',
            "controllers.pid.kp",
            "number",
        ),
        # bug 9: a sine starting after the end, scored rmse_sine = 0
        ('sine_amplitude = "1 mm"', SINE % "3 s", "control.reference.sines", "after the end"),
        # bug 10: the step after the end (StopIteration traceback)
        ('step_time = "0.2 s"', 'step_time = "2 s"', "control.reference.step_time", "never"),
        # an unknown setting: "unknown key", with the closest one
        (
            "[control.controllers.pid]",
            "[control.controllers.pid]\nkp_gain = 3",
            "controllers.pid.kp_gain",
            "did you mean 'kp'",
        ),
        # the EKF's own setting blamed on its own key, not on lqi.substeps
        (
            "[control.controllers.pid]",
            '[control.controllers.pid]\ntype = "lqi"\nestimator = "ekf"\nekf = { substeps = 0 }',
            "controllers.pid.ekf.substeps",
            "[1, 50]",
        ),
        # no measured signal for an estimator: refused, not the defaults
        ("measured = [", "measured = []\nmeasured_ = [", "control.measured", "non-empty"),
        # noise on a signal nobody measures: refused, not dropped
        (
            '"regulator.p_out" = "0.2 kPa"',
            '"regulator.p_out" = "0.2 kPa"\n"myofibril.aps1.chamber.p_gauge" = "1 kPa"',
            "control.noise",
            "not measured",
        ),
        # noise on a misspelt signal: the closest name offered
        (
            '"regulator.p_out" = "0.2 kPa"',
            '"regulator.p_ot" = "0.2 kPa"',
            "control.noise",
            "did you mean 'regulator.p_out'",
        ),
    ],
)
def test_unrunnable_scenes_are_refused_by_key(tmp_path, old, new, key, words):
    text = _short()
    assert old in text
    text = text.replace(old, new)
    if "measured_" in text:  # drop the original list
        text = re.sub(r"measured_ = \[.*?\]\n", "", text)
    with pytest.raises(ScenarioError) as info:
        run(parse_scenario(text, "bad.toml"), tmp_path / "out", quiet=True)
    assert key in str(info.value) and words in str(info.value), str(info.value)
