"""Scene kind joint_control: the reference schedule, a short run's metrics against the
recorded signals, and the refusals."""

import csv
import json
import math

import numpy as np
import pytest

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.scenarios import parse_scenario, run
from sarcomere.scenarios.joint_control import SEGMENT_S, reference

SCENE = """
[scenario]
name = "jc"
kind = "joint_control"

[model]
name = "{model}"
fidelity = "symmetric"
n = 2

[simulation]
stop_time = "{stop}"

[control]
co_contraction = {levels}

[control.controllers.lqi]
feedforward = "linear"
y_scale = [0.1, 1e-4]
"""


def _scene(model="joint", stop="1 s", levels='["0.15 MPa", "0.25 MPa"]'):
    return parse_scenario(SCENE.format(model=model, stop=stop, levels=levels))


def test_reference_steps_the_angle_then_the_sine_and_the_stiffness_per_segment():
    r = reference(0.0, [1.0, 2.0], 0.2, 0.1, 1.0)
    assert r(0.4) == (0.0, 1.0)
    assert r(0.5) == (0.2, 1.0)
    assert r(1.75)[0] == pytest.approx(0.3, abs=1e-12)  # a quarter period of the sine
    assert r(2.6) == (0.0, 1.0)
    assert r(SEGMENT_S + 0.1) == (0.0, 2.0)  # the next level, at rest
    assert r(2 * SEGMENT_S + 5.0)[1] == 2.0  # the last level held


@pytest.mark.parametrize(
    "kw, key",
    [
        ({"model": "myofibril"}, "model.name"),
        ({"levels": '["0.15 MPa"]'}, "control.co_contraction"),
        ({"levels": '["0.15 MPa", "0.5 MPa"]'}, "control.co_contraction"),
        ({"stop": "7 s"}, "simulation.stop_time"),
    ],
)
def test_refusals_name_the_key(tmp_path, kw, key):
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        run(_scene(**kw), tmp_path, quiet=True)


@pytest.mark.slow
def test_short_run_scores_the_recorded_signals(tmp_path):
    """1 s at the first level: the angle RMSE from the time series, no stiffness change
    (the angle coupling 0), the tendons' minimum and a real-time factor > 0."""
    run(_scene(), tmp_path, quiet=True)
    summary = json.loads((tmp_path / "summary.json").read_text())
    m = summary["metrics"]
    with open(tmp_path / "timeseries.csv") as f:
        rows = list(csv.DictReader(f))
    data = {k.split(" [")[0]: np.array([float(r[k]) for r in rows]) for k in rows[0]}
    err = data["joint.theta"] - data["reference"]
    assert m["lqi_angle_rmse_mrad"] == pytest.approx(1e3 * math.sqrt(np.mean(err**2)))
    assert m["lqi_coupling_angle_pct"] == 0.0
    slack = np.minimum(data["flexor_tendon.T"], data["extensor_tendon.T"])
    assert m["lqi_tendon_tension_min_N"] == pytest.approx(slack.min())
    assert m["lqi_real_time_factor"] > 0
