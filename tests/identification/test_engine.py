"""The compiled shooting engine and the Gauss-Newton under it, on generated records (fixed
seeds): the Jacobians of the residuals and constraints against central differences of
the engine's own values (every parameter column, random node columns, steps of 1 and 3
samples), the state scales, and a stalled step named by its time."""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.identification.experiments import Estimated, Noise, TimeSeries
from sarcomere.dynamics.identification.problem import Problem

OUTS = ["myofibril.length", "myofibril.aps1.chamber.p_gauge"]
NOISE = {"myofibril.length": Noise(2e-6), "myofibril.aps1.chamber.p_gauge": Noise(20.0)}
NAMES = ["regulator.tau", "myofibril.tube1.C", "myofibril.aps1.loss.d", "load.m"]


def _problem(seed: int, step: int = 1, interval: int = 7) -> Problem:
    """A random chain (n 1 or 2), load, step level and time, with data that are only
    placeholders (the Jacobian does not depend on them)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3))
    m = hanging_load(n, load_kg=float(rng.uniform(0.02, 0.1)))
    t = np.arange(0.0, 0.06 + 1e-9, 2e-3)
    u = np.where(t < float(rng.uniform(0.005, 0.02)), 0.0, float(rng.uniform(3e4, 9e4)))
    names = [k for k in NAMES if k in m.param_names]
    params = [
        Estimated(k, m.variables[k].unit, v, v / 5, v * 5)
        for k, v in ((k, m.variables[k].value) for k in names)
    ]
    uses = {k: (k, 1.0) for k in names}
    data = np.zeros((len(t), len(OUTS)))
    ts = TimeSeries("rec", m, t, u[:, None], OUTS, data, m.parameters(), uses, interval, step)
    return Problem(params, [ts], noise=NOISE)


@pytest.mark.slow
@pytest.mark.parametrize("seed, step", [(3, 1), (8, 3)])
def test_jacobians_match_central_differences(seed, step):
    pb = _problem(seed, step)
    theta = np.array([e.start for e in pb.params]) * np.random.default_rng(seed).uniform(
        0.7, 1.4, len(pb.params)
    )
    v = pb.initial_guess(theta)
    rng = np.random.default_rng(seed + 100)
    v[len(pb.params) :] += 1e-3 * rng.standard_normal(pb.n_v - len(pb.params))  # defects on
    w = pb.weights()
    lin = pb.linearize(v, w)
    cols = list(range(len(pb.params))) + list(rng.choice(pb.n_v - 4, 8, replace=False) + 4)
    for c in cols:
        h = 1e-5  # between the steps' Newton noise (1e-10) and the truncation error
        up, down = v.copy(), v.copy()
        up[c] += h
        down[c] -= h
        a, b = pb.linearize(up, w, False), pb.linearize(down, w, False)
        for got, hi, lo in ((lin.Jr, a.rw, b.rw), (lin.Jg, a.g, b.g)):
            fd = (hi - lo) / (2 * h)
            col = got[:, c].toarray().ravel()
            assert np.max(np.abs(fd - col)) <= 1e-4 * max(np.max(np.abs(col)), 1.0), c


def test_a_set_pressure_is_scaled_by_its_magnitude_not_its_nominal():
    pb = _problem(1)
    shoot = pb.shootings[0]
    k = shoot.model.state_names.index("regulator.p_set")
    level = float(np.max(shoot.u))
    assert shoot.model.nominal("x")[k] == 1.0  # 1 Pa: the model's own nominal
    assert level <= shoot.scale[k] < 2 * level  # the record's equilibrium, a power of two
    assert np.log2(shoot.scale[k]) == int(np.log2(shoot.scale[k]))


def test_a_failing_step_is_an_error_naming_its_time():
    pb = _problem(2)
    shoot = pb.shootings[0]
    S = np.full((shoot.model.nx, shoot.nodes), np.nan)
    with pytest.raises(SolverError, match=r"Radau IIA step from t = 0 s .* failed"):
        shoot.simulate(S, shoot.model.parameters())


def test_a_solve_whose_start_cannot_be_simulated_fails_with_its_reason():
    """A profile point may start where a step fails: the solve returns a failed Solution
    saying why (it raised UnboundLocalError before), and the profile goes on."""
    pb = _problem(2)
    v = pb.initial_guess(np.array([e.start for e in pb.params]))
    n = len(pb.params)
    v[n:] = np.nan  # no state can be stepped from
    sol = pb.solve(v, pb.weights())
    assert not sol.success and sol.cost == np.inf
    assert sol.status.startswith("evaluation failed at the start (") and "finite" in sol.status
