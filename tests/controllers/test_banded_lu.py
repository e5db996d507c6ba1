"""The bordered banded LU of the RTI's collocation Jacobians (:mod:`sarcomere.controllers.
banded_lu`): against numpy's dense solve, its structure check, and the Python RTI that
uses it against the dense lift's law."""

import casadi as cs
import numpy as np
import pytest

from sarcomere.controllers.banded_lu import BorderedBand, bordered_band
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.receding import TENSIONS
from sarcomere.dynamics import hanging_load, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

P = "regulator.p_cmd"


def chain_pattern(nx: int, d: int, rng) -> np.ndarray:
    """A collocation Jacobian's pattern (stage-major, dense d x d stage blocks) of a chain
    whose states couple with the next two, and one state (a random one) with all."""
    J = np.eye(nx, dtype=bool) | np.eye(nx, k=1, dtype=bool) | np.eye(nx, k=-2, dtype=bool)
    hub = rng.integers(nx)
    J[hub, :] = J[:, hub] = True
    return np.kron(np.ones((d, d), dtype=bool), J)


def test_the_bordered_band_solves_like_a_dense_lu():
    """Random values on a chain's pattern with a hub state (3 intervals, 7 right-hand
    sides): the band and the border found, and the solves equal numpy's dense LU."""
    rng = np.random.default_rng(5)
    nx, d, N, w = 40, 3, 3, 7
    pat = chain_pattern(nx, d, rng)
    structure, reason = bordered_band(pat, nx, d, w)
    assert reason == "" and structure["m"] == (nx - 1) * d  # the hub is the border
    assert max(structure["kl"], structure["ku"]) < 12
    n = nx * d
    mats = [np.where(pat, rng.normal(size=(n, n)), 0.0) + 4 * np.eye(n) for _ in range(N)]
    rhs = [rng.normal(size=(n, w)) for _ in range(N)]
    sparse = [cs.sparsify(cs.DM(M)) for M in mats]
    sp_rv = cs.horzcat(*sparse).sparsity()
    band = BorderedBand(structure, sp_rv, N)
    band.factor(np.concatenate([np.array(M.nonzeros()) for M in sparse]))
    for k in range(N):
        want = -np.linalg.solve(mats[k], rhs[k])
        assert np.allclose(band.solve(k, rhs[k]), want, rtol=1e-10, atol=1e-10)


def test_a_dense_jacobian_has_no_band_and_says_why():
    """Every state coupled with every other: the check falls back with its reason, and the
    RTI's "banded" is refused at n = 3 (its band would cost 98 % of the dense LU)."""
    structure, reason = bordered_band(np.ones((30, 30), dtype=bool), 10, 3, 5)
    assert structure is None and "of the dense LU's flops" in reason
    model = hanging_load(3, load_kg=0.02, flow_law="smooth", saturate=False)
    eq = solve_equilibrium(model, {P: 5e4})
    with pytest.raises(ParameterError, match="nmpc.linear_solver.*dense LU's flops"):
        NonlinearMPC(model, eq.u, 0.01, NMPCSettings(linear_solver="banded"))
    auto = NonlinearMPC(model, eq.u, 0.01).engine  # "auto": the dense LU, the reason kept
    assert "dense LU's flops" in auto.band_reason and not hasattr(auto.lift, "band")


@pytest.mark.slow
def test_the_banded_rti_gives_the_dense_lifts_commands():
    """n = 10 (the band pays): the Python RTI with the banded solves against the one with
    LAPACK's dense LU, sample by sample on the same measurements (fixed seed: states
    around random equilibria, random references): commands within 1e-6 of the input
    range, the same next guess, and equal to the law Function's."""
    model = hanging_load(10, load_kg=0.02, flow_law="smooth", saturate=False)
    rng = np.random.default_rng(11)
    s = NMPCSettings(soft_min=((TENSIONS, 0.19),), integral_gain=0.0)
    eq = solve_equilibrium(model, {P: 5e4})
    make = [NMPCSettings(**{**s.__dict__, "linear_solver": k}) for k in ("lapacklu", "auto")]
    dense, banded = (NonlinearMPC(model, eq.u, 0.01, k).engine for k in make)
    assert banded.lift.band.nb == 6  # regulator and one more state
    xs, p = dense.pb.xs, NonlinearMPC(model, eq.u, 0.01, make[0])._p
    span, u_prev = s.u_max - s.u_min, eq.u.copy()
    for _ in range(6):
        at = solve_equilibrium(model, {P: rng.uniform(2e4, 8e4)})
        x = np.asarray(at.x) + 2e-3 * xs * rng.normal(size=model.nx)
        ref = at["myofibril.length"] + 2e-4 * rng.normal() + np.zeros(s.horizon)
        law = [np.array(v).ravel() for v in banded.law(banded.memory, x, u_prev, ref, p)]
        a, b = dense.sample(x, u_prev, ref, p), banded.sample(x, u_prev, ref, p)
        assert a[2][0] == b[2][0] == 0  # no fallback
        assert b[0][0] == pytest.approx(a[0][0], abs=1e-6 * span)
        assert b[0][0] == pytest.approx(law[1][0], abs=1e-6 * span)
        assert np.allclose(banded.memory, dense.memory, rtol=1e-6, atol=1e-8)
        u_prev = a[0]
