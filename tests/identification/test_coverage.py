"""Coverage of the engine's 95 % Fisher intervals over noise replicates (fixed seed):
the truth is inside the interval of most replicates, as a 95 % interval must be.

Data: a 1-APS step response simulated by CVODES at rtol 1e-10 (an independent reference,
not the fit's own Radau steps); 12 noise replicates; two parameters (the regulator's time
constant and the tube conductance) fitted from the truth.
"""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.identification import uncertainty
from sarcomere.dynamics.identification.estimate import fit_from
from sarcomere.dynamics.identification.experiments import Estimated, Noise, TimeSeries
from sarcomere.dynamics.identification.problem import Problem

OUTS = ("myofibril.length", "myofibril.aps1.chamber.p_gauge")
SIGMA = np.array([2e-6, 20.0])  # m, Pa
NAMES = ("regulator.tau", "myofibril.tube1.C")
REPLICATES = 12


@pytest.mark.slow
def test_fisher_intervals_cover_the_truth(tight_record):
    """At least 10 of 12 replicates' 95 % intervals hold the truth (for a true 95 %
    interval, fewer happens with probability 2 %), and not by inflated intervals: each
    median half-width over 1.96 x the replicates' spread is below 2.5."""
    model = hanging_load(1, load_kg=0.05)
    truth = {
        NAMES[0]: 1.3 * model.variables[NAMES[0]].value,
        NAMES[1]: 0.7 * model.variables[NAMES[1]].value,
    }
    t = np.arange(0.0, 0.12 + 1e-3, 2e-3)
    u = np.where(t < 0.02, 0.0, 6e4)
    clean = tight_record(model, t, u, truth, OUTS)
    params = [
        Estimated(n, model.variables[n].unit, truth[n], truth[n] / 5, truth[n] * 5) for n in NAMES
    ]
    uses = {n: (n, 1.0) for n in NAMES}
    noise = {o: Noise(s) for o, s in zip(OUTS, SIGMA, strict=True)}
    rng = np.random.default_rng(2511)
    theta_true = np.log([truth[n] for n in NAMES])
    inside, estimates, half = np.zeros(len(NAMES), int), [], []
    for _ in range(REPLICATES):
        data = clean + rng.normal(size=clean.shape) * SIGMA
        ts = TimeSeries("step", model, t, u[:, None], OUTS, data, model.parameters(), uses, 10, 2)
        problem = Problem(params, [ts], noise=noise)
        fit = fit_from(problem, np.array([truth[n] for n in NAMES]))
        assert fit.solution.success
        sd = uncertainty.fisher(problem, fit.solution).sd_phi
        phi = np.log(fit.solution.theta)
        inside += np.abs(phi - theta_true) <= 1.96 * sd
        estimates.append(phi)
        half.append(1.96 * sd)
    assert np.all(inside >= 10), inside
    spread = np.std(estimates, axis=0, ddof=1)
    assert np.all(np.median(half, axis=0) / (1.96 * spread) < 2.5), (half, spread)
