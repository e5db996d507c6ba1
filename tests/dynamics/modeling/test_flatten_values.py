"""Flattening changes how the equations are solved, never their values.

The flattened Functions are checked against the declared equations solved numerically
(every connection, port and ``der_of`` rate an unknown, Newton on the raw residuals: no
elimination, no BLT order), their Jacobians against finite differences, and the
equilibrium's numeric row scales against the symbolic ones.
"""

import casadi as cs
import numpy as np
import pytest
import scipy.sparse as sp

from sarcomere.dynamics import assemblies
from sarcomere.dynamics.equilibrium import _row_scales
from sarcomere.dynamics.modeling import component
from sarcomere.dynamics.modeling.flatten import _connection_equations
from sarcomere.dynamics.newton import row_weights


@pytest.fixture
def captured(monkeypatch):
    """The Systems the set-ups flatten (the declarations before elimination)."""
    systems = []
    flatten = component.System.flatten

    def keep(self):
        systems.append(self)
        return flatten(self)

    monkeypatch.setattr(component.System, "flatten", keep)
    return systems


def _v(values) -> np.ndarray:
    return np.array(values, dtype=float).ravel()


def _raw_solution(system, model, x, u, p):
    """Every declared unknown and rate at ``(x, u, p)``, by Newton on the raw equations
    (started from the model's own values, so only a wrong model moves them); returns the
    values by name, ``dx/dt`` and the outputs from the declared expressions.

    A rate ``w = d e/dt`` is ``G dx/dt`` with ``G = de/dx`` through the raw equations
    (implicit function theorem: ``e`` depends on the states only, through positions that
    no rate moves)."""
    c = system._c
    eqs = [e[0] for e in c.equations]
    eqs += [e[0] for e in _connection_equations(c, dict(c.variables))]
    kinds = {n: v.kind for n, v in c.variables.items()}
    zn = [n for n, k in kinds.items() if k == "algebraic"]
    wn = [n for n, k in kinds.items() if k == "derivative"]
    z, w = (cs.vertcat(*[c.symbols[n] for n in names]) for names in (zn, wn))
    xs = cs.vertcat(*[c.symbols[n] for n in model.state_names])
    ders = cs.vertcat(*[c.ders[n] for n in model.state_names])
    e = cs.vertcat(*c.time_derivatives.values())
    res = cs.vertcat(*eqs)
    args = [z, w, xs, model.u, model.p]
    R = cs.Function("R", args, [res, *(cs.jacobian(res, v) for v in (z, xs, w))])
    E = cs.Function("E", args, [cs.jacobian(e, z), cs.jacobian(e, xs)])
    out = cs.Function("out", args, [ders, cs.jacobian(ders, z), cs.jacobian(ders, w)])
    ys = cs.Function("ys", args, [cs.vertcat(*c.outputs.values())])
    start = _v(model.function("signals")(x, model.z0(p), u, p))
    sig = dict(zip(model.signal_names, start, strict=True))
    zv = np.array([sig.get(n, 0.0) for n in zn])
    wv = np.array([sig.get(n, 0.0) for n in wn])
    G = np.zeros((len(wn), model.nx))
    for _ in range(50):  # Newton on [R(z, w) = 0; w - G f(z, w) = 0]
        r, Rz, Rx, Rw = (np.array(a, dtype=float) for a in R(zv, wv, x, u, p))
        if wn:
            Ez, Ex = (np.array(a, dtype=float) for a in E(zv, wv, x, u, p))
            G = Ex - Ez @ np.linalg.solve(Rz, Rx)
        f, fz, fw = (np.array(a, dtype=float) for a in out(zv, wv, x, u, p))
        rw = wv - G @ f.ravel()
        J = np.block([[Rz, Rw], [-G @ fz, np.eye(len(wn)) - G @ fw]])
        step = np.linalg.solve(J, -np.concatenate([r.ravel(), rw]))
        zv, wv = zv + step[: len(zn)], wv + step[len(zn) :]
        if np.max(np.abs(step)) <= 1e-15 * max(1.0, np.max(np.abs(zv))):
            break
    assert np.max(np.abs(_v(R(zv, wv, x, u, p)[0]))) < 1e-8
    f = _v(out(zv, wv, x, u, p)[0])
    values = dict(zip(zn + wn, np.concatenate([zv, wv]), strict=True))
    return values, f, _v(ys(zv, wv, x, u, p))


def _point(model, seed):
    rng = np.random.default_rng(seed)
    p = model.parameters()
    x = model.x0(p) * (1 + 0.02 * rng.standard_normal(model.nx)) + 1e-4 * rng.standard_normal(
        model.nx
    )
    u = model.u0(p) + 3e4 * rng.random(len(model.input_names))
    return x, u, p


CASES = {
    "hanging n=3 full": lambda: assemblies.hanging_load(3, load_kg=0.05),
    "hanging n=2 quasi_static": lambda: assemblies.hanging_load(2, fidelity="quasi_static"),
    "hanging n=2 static_chain": lambda: assemblies.hanging_load(2, fidelity="static_chain"),
    "isometric n=1 rigid": lambda: assemblies.isometric(1, length=0.05),
    "sprung load n=2": lambda: assemblies.sprung_load(2),
}


@pytest.mark.parametrize("case", CASES)
def test_flattened_functions_equal_the_declared_equations_solved_numerically(case, captured):
    model = CASES[case]()
    system = captured[-1]
    for seed in range(2):
        x, u, p = _point(model, seed)
        raw, f, y = _raw_solution(system, model, x, u, p)
        z = np.array([raw[n] for n in model.alg_names])
        if model.nz:
            alg = _v(model.function("alg")(x, z, u, p))
            assert np.max(np.abs(alg)) < 1e-9
        ode = _v(model.function("ode")(x, z, u, p))
        np.testing.assert_allclose(ode, f, rtol=1e-10, atol=1e-10 * np.max(np.abs(f)))
        outs = _v(model.function("y")(x, z, u, p))
        np.testing.assert_allclose(outs, y, rtol=1e-10, atol=1e-12)
        sig = _v(model.function("signals")(x, z, u, p))
        for name, value in zip(model.signal_names, sig, strict=True):
            if name in raw:
                assert value == pytest.approx(raw[name], rel=1e-9, abs=1e-12), name


@pytest.mark.parametrize("case", ["hanging n=3 full", "isometric n=1 rigid"])
def test_jacobians_match_finite_differences(case):
    model = CASES[case]()
    x, u, p = _point(model, 3)
    z = np.zeros(model.nz)
    ode = model.function("ode")
    A = np.array(model.function("dae_jac")(x, z, u, p)[0])
    lin = model.linearization(["myofibril.length"])(x=x, z=z, u=u, p=p)
    np.testing.assert_array_equal(np.array(lin["A"]), A)  # the same Jacobian, shared
    for j in range(model.nx):
        h = 1e-6 * max(abs(x[j]), model.nominal("x")[j])
        e = np.zeros(model.nx)
        e[j] = h
        fd = (_v(ode(x + e, z, u, p)) - _v(ode(x - e, z, u, p))) / (2 * h)
        scale = np.maximum(np.abs(A[:, j]), 1e-6 * np.max(np.abs(A)))
        assert np.max(np.abs(fd - A[:, j]) / scale) < 1e-4, model.state_names[j]
    fu = _v(ode(x, z, u + 1.0, p)) - _v(ode(x, z, u - 1.0, p))
    np.testing.assert_allclose(_v(np.array(lin["B"])), fu / 2.0, rtol=1e-5, atol=1e-12)


def test_numeric_row_scales_equal_the_symbolic_ones():
    """Dense, sparse and empty rows, zeros and NaN: the same numbers bit for bit."""
    rng = np.random.default_rng(1)
    rows, cols = [0, 0, 0, 1, 3, 3], [0, 1, 2, 1, 0, 2]
    pattern = cs.Sparsity.triplet(4, 3, rows, cols)
    Js = cs.SX.sym("J", pattern)
    s = cs.SX.sym("s", 3)
    f = cs.Function("f", [Js, s], [_row_scales(Js, s)])
    for values in (rng.standard_normal(6), [0.0, -2.0, np.nan, 0.0, np.nan, np.nan]):
        scale = rng.random(3) + 0.5
        J = sp.csc_matrix((values, (rows, cols)), shape=(4, 3))
        want = _v(f(cs.DM(J), scale))
        np.testing.assert_array_equal(row_weights(J, scale), want)
