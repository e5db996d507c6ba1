"""The step grid of the shooting engine: steps that span several samples, end at every
kink of the inputs and grow again after one; the states between step ends from the
collocation polynomial, checked against the library's adaptive integrator at tight
tolerance; the noise level read from data; and the automatic step."""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.identification.shooting import (
    RESIDUAL_TOL,
    Grid,
    Shooting,
    auto_step,
    kinks,
    noise_level,
    scales,
)
from sarcomere.dynamics.signals import Table
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate

OUTS = ("myofibril.length", "myofibril.aps1.chamber.p_gauge")


def test_kinks_are_the_samples_where_an_input_slope_changes():
    t = np.array([0.0, 0.1, 0.3, 0.4, 0.7, 1.0, 1.2])  # uneven samples
    ramp = np.array([0.0, 0.0, 2.0, 3.0, 6.0, 6.0, 6.0])  # 0 | slope 10 from 0.1 to 0.7 | 0
    assert kinks(t, ramp).tolist() == [1, 4]
    assert kinks(t, np.full(7, 5.0)).size == 0
    two = np.column_stack([np.zeros(7), [0, 0, 0, 0, 0, 1, 1.0]])  # the second input bends
    assert kinks(t, two).tolist() == [4, 5]
    noisy = np.random.default_rng(1).standard_normal(7)
    assert kinks(t, noisy).tolist() == [1, 2, 3, 4, 5]


@pytest.mark.parametrize("seed", range(6))
def test_a_generated_grid_covers_every_sample_and_never_steps_over_a_kink(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 400))
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n)) - 0.5e-3  # uneven sampling
    corners = np.sort(rng.choice(np.arange(1, n - 1), int(rng.integers(0, 6)), replace=False))
    u = np.zeros(n)
    for c in corners:  # a staircase of one-sample ramps
        u[c + 1 :] += rng.uniform(1e4, 3e4)
    step = int(rng.choice([1, 2, 4, 8, 16, 32]))
    interval = int(rng.integers(5, 80))
    g = Grid.of_record(t, u, step, interval)
    bent = set(kinks(t, u).tolist())
    assert g.k0[0] == 0 and g.k1[-1] == n - 1 and np.all(g.k0[1:] == g.k1[:-1])
    assert np.all(g.k1 - g.k0 >= 1) and np.all(g.k1 - g.k0 <= step)
    for a, b in zip(g.k0, g.k1, strict=True):
        assert not bent & set(range(a + 1, b)), (a, b)  # no kink inside a step
        last = max([k for k in bent if k <= a], default=None)
        if last is not None:  # after a kink: at most as long as the time since it
            assert b - a <= max(a - last, 1), (a, b, last)
    lengths = [g.k1[b - 1] - g.k0[a] for a, b in zip(g.first[:-1], g.first[1:], strict=True)]
    assert g.first[0] == 0 and g.first[-1] == len(g.k0)
    assert all(interval <= s < interval + step for s in lengths[:-1]), (interval, lengths)
    # the steps do not depend on the intervals (single and multiple shooting alike)
    single = Grid.of_record(t, u, step, None)
    assert np.array_equal(single.k0, g.k0) and single.first.tolist() == [0, len(g.k0)]
    k = np.arange(1, n)
    assert np.all((g.k0[g.of[1:]] < k) & (k <= g.k1[g.of[1:]]))
    np.testing.assert_allclose(g.w[1:].sum(axis=1), 1.0, rtol=0, atol=1e-12)  # a partition
    ends = np.isin(k, g.k1)
    assert np.all(g.w[1:][ends] == [0.0, 0.0, 0.0, 1.0])


def _record(seed: int, dt: float = 1e-3, t_end: float = 0.4):
    """A random chain, load and staircase, and its outputs by CVODES at rtol 1e-10."""
    rng = np.random.default_rng(seed)
    m = hanging_load(int(rng.integers(1, 4)), load_kg=float(rng.uniform(0.02, 0.12)))
    t = np.arange(0.0, t_end + dt / 2, dt)
    u = np.zeros_like(t)
    for at in np.sort(rng.uniform(0.01, t_end - 0.05, 2)):
        u[t > at] += rng.uniform(2e4, 5e4)
    eq = solve_equilibrium(m, {"regulator.p_cmd": 0.0}, {})
    res = simulate(
        m,
        t[-1],
        x0=eq.x,
        inputs={"regulator.p_cmd": Table(times=tuple(t), values=tuple(u), unit="Pa")},
        t_out=t,
        settings=SolverSettings(rtol=1e-10, atol=1e-12),
    )
    return m, t, u, eq.x, np.vstack([res[o] for o in OUTS])


@pytest.mark.parametrize("seed", [2, 5])
def test_coarse_steps_follow_the_tight_reference_between_their_ends(seed):
    m, t, u, x0, ref = _record(seed)
    scale = scales(m, [x0])

    def at(step):
        sh = Shooting.of(m, t, u[:, None], 50, (), 0, OUTS, scale, step)
        return sh.predict(x0 / scale, m.parameters()), len(sh.grid.k0)

    fine, n_fine = at(1)
    coarse, n_coarse = at(8)
    assert n_coarse < n_fine / 4  # the grid is coarse, not one step per sample
    span = np.ptp(ref, axis=1)
    err_fine = np.max(np.abs(fine - ref), axis=1) / span
    err_coarse = np.max(np.abs(coarse - ref), axis=1) / span
    # both within 1e-4 of the span (the largest, 3e-5: the sample after a one-sample ramp,
    # alike in both), and so is the coarse grid's own part (a wrong weight or a step across a
    # kink costs 1e-3 and more)
    assert np.all(err_fine < 1e-4) and np.all(err_coarse < 1e-4), (err_fine, err_coarse)
    gap = np.max(np.abs(coarse - fine), axis=1) / span
    assert np.all(gap < 1e-4), gap


def test_the_noise_level_is_read_from_the_data():
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 1.0, 1001)
    smooth = np.column_stack([1e-2 * (1 - np.exp(-t / 0.05)), 1e5 * np.sin(3 * t)])
    sigma = np.array([2e-5, 500.0])
    noisy = smooth + sigma * rng.standard_normal(smooth.shape)
    noisy[::7, 0] = np.nan  # not measured there
    # a median of correlated differences: within 15 % (all a step tolerance needs)
    np.testing.assert_allclose(noise_level(noisy), sigma, rtol=0.15)
    assert np.all(noise_level(smooth) < 1e-3 * sigma)


def test_the_automatic_step_meets_its_tolerance_and_is_one_for_exact_data():
    m, t, u, x0, ref = _record(3)
    scale = scales(m, [x0])

    def make(step):
        return Shooting.of(m, t, u[:, None], 50, (), 0, OUTS, scale, step)

    p = m.parameters()
    assert auto_step(make, x0 / scale, p, ref.T) == 1  # exact data: the finest grid
    sigma = np.array([20e-6, 500.0])
    noisy = ref.T + sigma * np.random.default_rng(0).standard_normal(ref.T.shape)
    step = auto_step(make, x0 / scale, p, noisy)
    assert step > 1
    gap = np.max(np.abs(make(step).predict(x0 / scale, p) - make(1).predict(x0 / scale, p)), 1)
    assert np.all(gap <= 0.01 * noise_level(noisy)), (step, gap)


def test_a_march_from_another_start_is_not_the_last_one():
    """A shooting keeps nothing from one call to the next (a cache of stages once reused
    the last march's for another start): two marches at the same parameters from
    different states give their own results, those of a fresh shooting."""
    m, t, u, x0, _ = _record(4)
    scale = scales(m, [x0])
    sh = Shooting.of(m, t, u[:, None], 50, (), 0, OUTS, scale, 8)
    p = m.parameters()
    other = x0 / scale * 1.001
    first, second = sh.march(x0 / scale, p), sh.march(other, p)
    fresh = Shooting.of(m, t, u[:, None], 50, (), 0, OUTS, scale, 8).march(other, p)
    assert np.abs(first - second).max() > 1e-6
    np.testing.assert_array_equal(second, fresh)


def test_a_step_whose_newton_fails_is_found_from_substeps():
    """Newton (both the sparse LU's and CasADi's) made to fail on the whole 8-sample steps
    unless it starts within 1e-3 (relative) of their solution: the stages guessed from
    substeps are that close (2e-4 after the input's step), the step's start and the
    previous polynomial are not (0.4 and 2e-2), and the march ends where the unhindered
    one does."""
    import dataclasses

    m, t, u, x0, _ = _record(2)
    scale = scales(m, [x0])
    p = m.parameters()
    plain = Shooting.of(m, t, u[:, None], 50, (), 0, OUTS, scale, 8)
    want = plain.march(x0 / scale, p)
    inner = plain.engine.step
    big = 8 * (t[1] - t[0])
    rescued = []

    def step(x, guess, q, p_, sc):
        V, r = inner(x, guess, q, p_, sc)
        off = np.abs(np.reshape(guess, V.shape) - V) / np.maximum(np.abs(V), 1.0)
        if abs(q[-1] - big) < 1e-12 and off.max() > 1e-3:
            return V, np.array([[1.0]])  # "Newton failed"
        if q[-1] < big - 1e-12:
            rescued.append(q[-1])
        return V, r

    lu_inner = plain.engine.lu_step

    def lu_step(x, guess, q, p_, sc):  # the sparse LU's Newton hindered alike
        V, r, last = lu_inner(x, guess, q, p_, sc)
        off = np.abs(np.reshape(guess, V.shape) - V) / np.maximum(np.abs(V), 1.0)
        if abs(q[-1] - big) < 1e-12 and off.max() > 1e-3:
            return np.reshape(guess, V.shape), np.array([[1.0]]), np.array([[1.0]])  # no progress
        return V, r, last

    hindered = Shooting.of(m, t, u[:, None], 50, (), 0, OUTS, scale, 8)
    hindered.engine = dataclasses.replace(plain.engine, step=step, lu_step=lu_step)
    got = hindered.march(x0 / scale, p)
    assert rescued  # some steps were found from substeps
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", [5])
def test_the_sparse_lu_newton_lands_where_casadis_pivoting_qr_does(seed):
    """Every step of a generated march (1-3 units, a two-level staircase): the engine's
    Newton with the sparse LU (no pivoting), from the previous step's polynomial, and
    CasADi's ``fast_newton`` (pivoting sparse QR) from the same guess agree to 1e-9 in
    scaled states, each with a residual the engine accepts (``RESIDUAL_TOL``)."""
    m, t, u, x0, _ = _record(seed)
    scale = scales(m, [x0])
    p = m.parameters()
    sh = Shooting.of(m, t, u[:, None], None, (), 0, OUTS, scale, 4)
    g, eng = sh.grid, sh.engine
    x, last = x0 / scale, None
    for s in range(len(g.k0)):
        guess = np.repeat(x[:, None], 3, axis=1) if last is None else (g.ahead[s] @ last).T
        V_lu = guess
        for _ in range(3):
            V_lu, res_lu, dv = eng.lu_step(x, V_lu, g.q[s], p, scale)
            if dv.item() <= 1e-10:
                break
        V_qr, res_qr = eng.step(x, guess, g.q[s], p, scale)
        assert max(res_lu.item(), res_qr.item()) <= RESIDUAL_TOL, (s, res_lu, res_qr)
        np.testing.assert_allclose(V_lu, V_qr, rtol=0, atol=1e-9)
        last = np.vstack([x, V_qr.T])
        x = V_qr[:, -1]
