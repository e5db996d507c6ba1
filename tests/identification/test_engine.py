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


@pytest.mark.parametrize("seed", [4])
def test_equilibria_restored_by_quick_newton_equal_the_continued_ones(seed):
    """``restore`` at a trial point (parameters moved, equilibrium unknowns at a linear
    guess 1 % off) solves every equilibrium (a record's first node, three static points)
    as :func:`solve_equilibrium` does from the model's start, to 1e-7 in scaled units
    (both to a weighted residual of 1e-10, which leaves the unknowns about 1e-8 apart; the
    Gauss-Newton's constraint tolerance is 1e-6); a guess the quick Newton cannot use
    (NaN) falls back to that continuation."""
    from sarcomere.dynamics.identification.experiments import StaticPoint, measured

    pb0 = _problem(seed)
    m, ts = pb0.series[0].model, pb0.series[0]
    points = [
        StaticPoint(f"s{k}", m, np.array([level]), m.parameters(), ts.uses)
        for k, level in enumerate((2e4, 5e4, 8e4))
    ]
    targets = [measured(pt.name, "myofibril.length", 0.1) for pt in points]
    pb = Problem(pb0.params, [ts], points, targets, noise=NOISE)
    theta = np.array([e.start for e in pb.params])
    v = pb.initial_guess(theta)
    rng = np.random.default_rng(seed)
    moved = theta * rng.uniform(0.8, 1.25, len(theta))
    trial = v.copy()
    trial[: len(theta)] = [e.to_phi(t) for e, t in zip(pb.params, moved, strict=True)]
    ts_slots = np.arange(len(theta), len(theta) + m.nx)
    eq_slots = np.r_[ts_slots, np.arange(pb._w_offset, len(v))]
    trial[eq_slots] *= 1.01  # the Gauss-Newton step's linear guess is close, not exact
    quick = pb.restore(trial)
    np.testing.assert_array_equal(pb._restored_quickly(trial), quick)  # not the fallback
    exact = pb.initial_guess(moved)  # continued by solve_equilibrium from the model's start
    np.testing.assert_allclose(quick[eq_slots], exact[eq_slots], rtol=0, atol=1e-7)
    # the nodes other than the first are left as they were (lifted)
    rest = np.setdiff1d(np.arange(len(theta), pb._w_offset), ts_slots)
    np.testing.assert_array_equal(quick[rest], trial[rest])
    unusable = trial.copy()
    unusable[eq_slots] = np.nan
    np.testing.assert_allclose(pb.restore(unusable)[eq_slots], exact[eq_slots], atol=1e-7)
