"""The identification engine against independent references: data simulated by the
library's adaptive integrator at tight tolerance (not the fit's own Radau steps), central
finite differences of the Jacobian, the empirical spread of replicate fits, and a
parameter pair that enters the equations only as a product."""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.identification import uncertainty
from sarcomere.dynamics.identification.estimate import fit_from
from sarcomere.dynamics.identification.experiments import Estimated, Noise, TimeSeries
from sarcomere.dynamics.identification.problem import Problem

OUTS = ["myofibril.length", "myofibril.aps1.chamber.p_gauge"]
SIGMA = {"myofibril.length": 2e-6, "myofibril.aps1.chamber.p_gauge": 20.0}
C = "myofibril.tube1.C"


@pytest.fixture
def record(tight_record):
    """``record(seed, truth, dt=2e-3, t_end=0.2) -> (model, t, u, data)``: a random load
    and step level (fixed ``seed``) and the response from the equilibrium, by CVODES at
    rtol 1e-10 (the reference the fit must reproduce)."""

    def make(seed: int, truth: dict, dt: float = 2e-3, t_end: float = 0.2):
        rng = np.random.default_rng(seed)
        load = float(rng.uniform(0.02, 0.1))
        level = float(rng.uniform(3e4, 8e4))
        m = hanging_load(1, load_kg=load)
        t = np.arange(0.0, t_end + dt / 2, dt)
        u = np.where(t < 0.02, 0.0, level)
        return m, t, u, tight_record(m, t, u, truth, OUTS)

    return make


def _problem(m, t, u, data, names, interval=10, step=2):
    params = [
        Estimated(
            n,
            m.variables[n].unit,
            m.variables[n].value,
            m.variables[n].value / 5,
            m.variables[n].value * 5,
        )
        for n in names
    ]
    uses = {n: (n, 1.0) for n in names}
    ts = TimeSeries("step", m, t, u[:, None], OUTS, data, m.parameters(), uses, interval, step)
    noise = {o: Noise(SIGMA[o]) for o in OUTS}
    return Problem(params, [ts], noise=noise)


def _truth(m, factors):
    return {n: f * m.variables[n].value for n, f in factors.items()}


@pytest.mark.slow
def test_recovers_known_parameters_from_noise_free_data(record):
    base = hanging_load(1)
    truth = _truth(base, {"regulator.tau": 1.4, C: 0.6})
    m, t, u, data = record(7, truth)
    pb = _problem(m, t, u, data, list(truth))
    fit = fit_from(pb, np.array([m.variables[n].value for n in truth]))
    assert fit.solution.success, fit.solution.status
    np.testing.assert_allclose(fit.solution.theta, list(truth.values()), rtol=2e-4)


@pytest.mark.slow
def test_single_shooting_is_the_same_problem(record):
    base = hanging_load(1)
    truth = _truth(base, {"regulator.tau": 1.2})
    m, t, u, data = record(3, truth, t_end=0.08)
    multi = _problem(m, t, u, data, list(truth), interval=10)
    single = _problem(m, t, u, data, list(truth), interval=None)
    assert single.shootings[0].nodes == 1 and multi.shootings[0].nodes == 4
    theta = np.array(list(truth.values()))
    costs = [p.evaluate(p.initial_guess(theta), p.weights()).cost for p in (multi, single)]
    assert costs[0] == pytest.approx(costs[1], rel=1e-9)
    assert costs[0] < 0.5  # the fit's Radau steps reproduce CVODES' data within the noise


@pytest.mark.slow
def test_sensitivities_match_central_differences(record):
    base = hanging_load(1)
    truth = _truth(base, {"regulator.tau": 0.8, C: 1.3})
    m, t, u, data = record(11, truth, t_end=0.1)
    pb = _problem(m, t, u, data, list(truth))
    theta = np.array(list(truth.values()))
    w = pb.weights()
    sol = pb.evaluate(pb.initial_guess(theta), w)
    S = uncertainty.sensitivities(pb, sol)
    h = 1e-5
    for k in range(len(theta)):
        cols = []
        for sign in (1, -1):
            th = theta.copy()
            th[k] *= np.exp(sign * h)  # log-scaled: d/dphi
            cols.append(pb.evaluate(pb.initial_guess(th), w).residuals * w)
        fd = (cols[0] - cols[1]) / (2 * h)
        np.testing.assert_allclose(S[:, k], fd, atol=2e-5 * np.abs(fd).max())


@pytest.mark.slow
def test_product_pair_flagged_structurally_non_identifiable(record):
    """The tube's conductance C and its reference density rho0 enter only as C * rho0
    (ISO 6358 mass flow): a flat direction, named, for both."""
    m, t, u, data = record(5, {})
    pb = _problem(m, t, u, data, ["regulator.tau", C, "myofibril.tube1.rho0"])
    theta = np.array([m.variables[n].value for n in ("regulator.tau", C, "myofibril.tube1.rho0")])
    sol = pb.evaluate(pb.initial_guess(theta), pb.weights())
    fis = uncertainty.fisher(pb, sol)
    assert len(fis.flat) == 1
    assert fis.singular_values[-1] < 1e-9 * fis.singular_values[0]
    verdicts = uncertainty.verdicts(pb, fis, None)
    assert [v["verdict"] for v in verdicts] == [
        "identifiable",
        "structurally non-identifiable",
        "structurally non-identifiable",
    ]
    assert f"{C}^+1.00 * myofibril.tube1.rho0^-1.00" in verdicts[1]["why"] or (
        f"{C}^-1.00 * myofibril.tube1.rho0^+1.00" in verdicts[1]["why"]
    )
    assert np.isinf(fis.sd[1]) and np.isfinite(fis.sd[0])


def test_a_crossing_closed_by_a_correlated_bound_is_not_identifiability(record):
    """The tube's conductance C and the chamber's dead volume V0 set the filling rate
    mostly as C / V0 (correlation 0.9999999): with V0 boxed in to -3 % / +50 %, C's profile
    crosses the threshold on both sides, but only because V0 sits on a bound there. The
    verdict says so (before, C read "identifiable" with a 0.1 %-wide interval)."""
    m, t, u, data = record(5, {})
    data = data + np.random.default_rng(0).standard_normal(data.shape) * [SIGMA[o] for o in OUTS]
    V = "myofibril.aps1.chamber.V0"
    c, v = m.variables[C].value, m.variables[V].value
    params = [
        Estimated(C, m.variables[C].unit, c, c / 20, c * 20),
        Estimated(V, m.variables[V].unit, v, v * 0.97, v * 1.5),
    ]
    uses = {n: (n, 1.0) for n in (C, V)}
    ts = TimeSeries("step", m, t, u[:, None], OUTS, data, m.parameters(), uses, 10)
    pb = Problem(params, [ts], noise={o: Noise(SIGMA[o]) for o in OUTS})
    sol = fit_from(pb, np.array([c, v])).solution
    assert sol.success, sol.status
    fis = uncertainty.fisher(pb, sol)
    assert abs(fis.correlation[0, 1]) > uncertainty.COUPLED
    prof = uncertainty.profile(pb, sol, 0, fis.sd_phi[0])
    assert prof.crosses and prof.on_bounds == ((1,), (1,))
    verdict = uncertainty.verdicts(pb, fis, {0: prof})[0]
    assert verdict["verdict"] == "practically non-identifiable", verdict
    assert "lower and upper side" in verdict["why"] and V in verdict["why"]


def test_profile_interval_of_a_near_linear_parameter_is_the_fisher_interval(record):
    """The hanging mass enters the length almost linearly: its profile is a parabola
    and its 95 % profile interval must be the Fisher one (before, the crossing was
    interpolated linearly in the rise, from one step of 3.4 sd: 0.57 of the width)."""
    m, t, u, data = record(11, {})
    data = data + np.random.default_rng(1).standard_normal(data.shape) * [SIGMA[o] for o in OUTS]
    names = ["regulator.tau", "load.m"]
    pb = _problem(m, t, u, data, names)
    sol = fit_from(pb, np.array([m.variables[n].value for n in names])).solution
    assert sol.success, sol.status
    fis = uncertainty.fisher(pb, sol)
    prof = uncertainty.profile(pb, sol, 1, fis.sd_phi[1])
    low, high = fis.interval[1]
    assert prof.low == pytest.approx(low, abs=0.02 * (high - low))
    assert prof.high == pytest.approx(high, abs=0.02 * (high - low))


@pytest.mark.slow
def test_fisher_covariance_matches_replicate_spread(record):
    """8 noise replicates (fixed seed): the spread of the estimates agrees with the Fisher
    standard deviations (the sample sd of 8 values is within 0.4-1.7x of the true one
    with 99 % probability)."""
    base = hanging_load(1)
    truth = _truth(base, {"regulator.tau": 1.3, C: 0.7})
    m, t, u, clean = record(21, truth, t_end=0.12)
    rng = np.random.default_rng(1)
    sd = np.array([SIGMA[o] for o in OUTS])
    theta0 = np.array(list(truth.values()))
    estimates, fisher_sd = [], None
    for _ in range(8):
        pb = _problem(m, t, u, clean + rng.normal(size=clean.shape) * sd, list(truth))
        fit = fit_from(pb, theta0)
        assert fit.solution.success
        estimates.append(fit.solution.theta)
        if fisher_sd is None:
            fisher_sd = uncertainty.fisher(pb, fit.solution).sd
    ratio = np.std(estimates, axis=0, ddof=1) / fisher_sd
    assert np.all((ratio > 0.4) & (ratio < 1.7)), ratio


def test_estimated_parameter_refuses_bad_bounds():
    with pytest.raises(ParameterError, match="inside its bounds"):
        Estimated("a", "s", 2.0, 0.1, 1.0)
    with pytest.raises(ParameterError, match="low > 0"):
        Estimated("a", "s", 0.5, 0.0, 1.0)
