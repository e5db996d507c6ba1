"""Fits off the packaged path: generated muscles (2, 3 and 4 units; random load, staircase of
pressure levels, true time constant and tube conductance shared by every unit, noise; a
fixed seed each), their data simulated by CVODES at rtol 1e-10 (not the fit's own Radau
steps), fitted from the model's defaults by both shooting methods with the step chosen
automatically.

What would fail: a fit that stops short or off the truth on a chain of more than one
unit (a parameter shared across units mapped wrongly, a unit's states scaled or ordered
wrongly), a step grid that misses a generated staircase's kinks or coarsens beyond the
noise, or Fisher standard deviations that understate the real error."""

from __future__ import annotations

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.identification import uncertainty
from sarcomere.dynamics.identification.estimate import fit_from
from sarcomere.dynamics.identification.experiments import Estimated, Noise, TimeSeries
from sarcomere.dynamics.identification.problem import Problem

SIGMA_LENGTH, SIGMA_PRESSURE = 5e-6, 50.0  # m, Pa
DT = 2e-3  # s: 500 Hz
T_END = 0.3  # s


def outputs(n: int) -> list[str]:
    """The chain's length and the first and last unit's chamber pressures."""
    return ["myofibril.length", *(f"myofibril.aps{i}.chamber.p_gauge" for i in (1, n))]


def sigma(n: int) -> dict[str, float]:
    return {o: SIGMA_LENGTH if o.endswith("length") else SIGMA_PRESSURE for o in outputs(n)}


def generated(record, seed: int, n: int):
    """``n`` units; the muscle, its record (t, u, noisy data), the true values, the
    estimated parameters and where they enter the model (``record``: the
    ``tight_record`` fixture)."""
    rng = np.random.default_rng(seed)
    m = hanging_load(n, load_kg=float(rng.uniform(0.02, 0.12)))
    tubes = [f"myofibril.tube{i}.C" for i in range(1, n + 1)]
    tau0, c0 = m.variables["regulator.tau"].value, m.variables[tubes[0]].value
    off = np.exp(rng.choice([-1.0, 1.0], 2) * rng.uniform(0.35, 0.7, 2))  # 0.5-0.7, 1.4-2
    truth = {"regulator.tau": tau0 * off[0], "C": c0 * off[1]}
    params = {"regulator.tau": truth["regulator.tau"], **{c: truth["C"] for c in tubes}}
    t = np.arange(0.0, T_END + DT / 2, DT)
    k = int(rng.integers(2, 4))  # levels after the first
    times = np.sort(rng.uniform(0.02, T_END - 0.08, size=k))
    levels = np.sort(rng.uniform(2e4, 9e4, size=k))
    u = np.zeros_like(t)
    for when, level in zip(times, levels, strict=True):
        u[t >= when] = level
    clean = record(m, t, u, params, outputs(n))
    data = clean + rng.standard_normal(clean.shape) * list(sigma(n).values())
    estimated = [
        Estimated("regulator.tau", "s", tau0, tau0 / 5, tau0 * 5),
        Estimated("C", m.variables[tubes[0]].unit, c0, c0 / 5, c0 * 5),
    ]
    uses = {"regulator.tau": ("regulator.tau", 1.0), **{c: ("C", 1.0) for c in tubes}}
    return m, t, u, data, truth, estimated, uses


@pytest.mark.slow  # a CVODES record and two fits per seed, and each n's engine compiled once
@pytest.mark.parametrize(("seed", "n"), [(0, 2), (1, 3), (2, 4)])
def test_a_generated_muscle_is_recovered_within_its_fisher_intervals(tight_record, seed, n):
    m, t, u, data, truth, estimated, uses = generated(tight_record, seed, n)
    noise = {o: Noise(sd) for o, sd in sigma(n).items()}
    start = np.array([e.start for e in estimated])
    costs = []
    for interval in (25, None):  # multiple, then single shooting
        p = m.parameters()
        ts = TimeSeries("gen", m, t, u[:, None], outputs(n), data, p, uses, interval, step=None)
        pb = Problem(estimated, [ts], noise=noise)
        sol = fit_from(pb, start).solution
        assert sol.success, (seed, interval, sol.status)
        fis = uncertainty.fisher(pb, sol)
        # the truth within 4 standard deviations (in the search variable, log theta)
        z = (np.log(sol.theta) - np.log([truth[e.name] for e in estimated])) / fis.sd_phi
        assert np.all(np.abs(z) < 4), (seed, interval, z)
        # chi-squared of the fit against its 2 * n - 2 degrees of freedom: 6 sigma
        dof = data.size - len(estimated)
        assert abs(sol.cost - dof) < 6 * np.sqrt(2 * dof), (seed, interval, sol.cost, dof)
        costs.append(sol.cost)
    # both methods integrate on the same grid: the same optimum
    assert costs[0] == pytest.approx(costs[1], abs=0.1), costs
