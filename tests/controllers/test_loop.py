"""The sampled loop (zero-order hold, noise, disturbance, clipping) and its metrics."""

import math

import numpy as np
import pytest

from sarcomere.controllers import operating_point
from sarcomere.controllers.base import Controller
from sarcomere.controllers.loop import Disturbance, run_closed_loop
from sarcomere.controllers.metrics import rmse, step_response_metrics
from sarcomere.dynamics import Staircase, hanging_load, simulate
from sarcomere.dynamics.errors import ParameterError

DT = 0.01
L, P = "myofibril.length", "regulator.p_cmd"


class Schedule(Controller):
    """Open loop: the input from a table of sample values (a test double)."""

    slug = "schedule"

    def __init__(self, values, outputs=(L,)):
        super().__init__(DT, [P], list(outputs), {P: 0.0}, {P: 1e5})
        self.values, self.seen = list(values), []

    def update(self, t, y, r):
        self.seen.append(dict(y))
        return {P: self.values[round(t / DT)]}


@pytest.fixture(scope="module")
def plant():
    m = hanging_load(1, load_kg=0.02)
    return m, operating_point(m, {P: 5e4})


def test_zero_order_hold_matches_simulate_with_a_staircase(plant):
    m, op = plant
    values = [5e4 + 1e4 * (k % 5) for k in range(30)]
    run = run_closed_loop(m, Schedule(values), op, lambda t: op[L], 0.3, output=L)
    ref = simulate(
        m,
        0.29,
        {P: Staircase(levels=tuple(values), dwell=DT)},
        x0=op.x,
        t_out=np.arange(30) * DT,
    )
    np.testing.assert_allclose(run.result[L], ref[L], rtol=0, atol=1e-9)
    np.testing.assert_allclose(run.result[P], values)  # the input held from each sample


def test_noise_is_seeded_and_has_its_standard_deviation(plant):
    m, op = plant
    std = 1e-4
    runs = [
        run_closed_loop(
            m,
            Schedule([5e4] * 400),
            op,
            lambda t: op[L],
            4.0,
            output=L,
            noise_std={L: std},
            seed=s,
        )
        for s in (1, 1, 2)
    ]
    noise = runs[0].result["measured"] - runs[0].result[L]
    assert np.std(noise) == pytest.approx(std, rel=0.1)
    np.testing.assert_array_equal(runs[0].result["measured"], runs[1].result["measured"])
    assert not np.array_equal(runs[0].result["measured"], runs[2].result["measured"])


def test_load_disturbance_ends_at_the_heavier_equilibrium(plant):
    m, op = plant
    run = run_closed_loop(
        m,
        Schedule([5e4] * 300),
        op,
        lambda t: op[L],
        3.0,
        output=L,
        disturbance=Disturbance(0.5, "load.m", 0.05),
    )
    heavy = operating_point(m, {P: 5e4}, load_kg=0.07)
    t, y = run.result.index, run.result[L]
    assert np.all(y[t < 0.5] == pytest.approx(op[L], abs=1e-9))
    assert y[-1] == pytest.approx(heavy[L], abs=2e-5)


def test_unreachable_reference_is_clipped_with_a_warning(plant):
    m, op = plant
    with pytest.warns(UserWarning, match="clipped"):
        run = run_closed_loop(
            m, Schedule([5e4] * 10), op, lambda t: 1.0, 0.1, output=L, reachable=(0.1, 0.2)
        )
    assert np.all(run.result["reference"] == 0.2)


def test_bad_loop_settings(plant):
    m, op = plant
    with pytest.raises(ParameterError, match="noise_std"):
        run_closed_loop(m, Schedule([5e4]), op, lambda t: 0, 0.01, output=L, noise_std={L: -1})
    with pytest.raises(ParameterError, match="stop_time"):
        run_closed_loop(m, Schedule([5e4]), op, lambda t: 0, 0.001, output=L)


def test_step_metrics_of_a_second_order_response():
    zeta, wn = 0.3, 20.0
    t = np.linspace(0, 3, 30001)
    wd = wn * math.sqrt(1 - zeta**2)
    phi = math.acos(zeta)
    y = 1 - np.exp(-zeta * wn * t) * np.sin(wd * t + phi) / math.sqrt(1 - zeta**2)
    got = step_response_metrics(t, 2 + y, 2.0, 3.0, 0.0, 3.0)
    assert got["overshoot_pct"] == pytest.approx(
        100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), rel=1e-4
    )
    # 2 % settling: the envelope exp(-zeta wn t)/sqrt(1-zeta^2) bounds it from above
    assert got["settling_time_s"] <= math.log(50 / math.sqrt(1 - zeta**2)) / (zeta * wn)
    assert got["settling_time_s"] > 0.5 * math.log(50) / (zeta * wn)
    down = step_response_metrics(t, 2 - y, 2.0, 1.0, 0.0, 3.0)  # a step down: the same
    assert down == pytest.approx(got)
    assert rmse(np.array([1.0, 3.0]), np.array([0.0, 0.0])) == pytest.approx(math.sqrt(5))


def test_simulator_is_untouched_by_noise(plant):
    """Noise enters what the controller reads, never the plant: the true output equals
    an exact run's."""
    m, op = plant
    c1, c2 = Schedule([6e4] * 50), Schedule([6e4] * 50)
    exact = run_closed_loop(m, c1, op, lambda t: 0, 0.5, output=L)
    noisy = run_closed_loop(m, c2, op, lambda t: 0, 0.5, output=L, noise_std={L: 1e-3})
    np.testing.assert_array_equal(exact.result[L], noisy.result[L])
    assert c2.seen[3][L] != c1.seen[3][L]


class Previewed(Schedule):
    """A schedule that takes three samples of preview and records them (a test double)."""

    preview_samples = 3

    def set_preview(self, values):
        self.previews.append(list(values[L]))


def test_preview_hands_the_reference_at_the_next_samples_clipped(plant):
    m, op = plant
    ctl = Previewed([5e4] * 4)
    ctl.previews = []
    ramp = lambda t: 0.1 + t  # noqa: E731
    with pytest.warns(UserWarning, match="clipped"):
        run_closed_loop(m, ctl, op, ramp, 0.04, output=L, reachable=(0.0, 0.125), preview=True)
    assert np.allclose(ctl.previews[0], [0.11, 0.12, 0.125])  # t + dt, t + 2 dt, clipped
    assert np.allclose(ctl.previews[1], [0.12, 0.125, 0.125])
    assert len(ctl.previews) == 4
    ctl.previews = []
    run_closed_loop(m, ctl, op, ramp, 0.04, output=L)  # not known ahead: no preview
    assert ctl.previews == []


def test_a_controller_without_preview_refuses_one():
    with pytest.raises(ParameterError, match="preview"):
        Schedule([5e4]).set_preview({L: [0.1]})
