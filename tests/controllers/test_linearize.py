"""The linearisation against independent references: central finite differences of the
flattened Functions, the nonlinear model's step and sine responses, python-control's tools."""

import control as ct
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np
import pytest
import scipy.linalg as sla

from sarcomere.controllers.linearize import classify_poles, linearize, operating_point
from sarcomere.dynamics import Simulator, Sine, hanging_load
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.labels import from_label

L = "myofibril.length"
P = "regulator.p_cmd"


@pytest.fixture(scope="module")
def plant():
    m = hanging_load(1, load_kg=0.02)
    return m, operating_point(m, {P: 5e4})


def _length(m, X, Z, U, p):
    """The length along a trajectory (rows of X, Z, U)."""
    F = m.signals_function([L], len(X))
    return np.array(F(X.T, Z.T, U.T, np.repeat(p[:, None], len(X), axis=1))).ravel()


def _reduced(m, x, u, p, z_guess):
    """ode and signals with ``z`` solved from ``alg = 0`` (Newton, numpy): the DAE's
    state-space form, evaluated without the implicit function theorem."""
    z = np.array(z_guess, dtype=float)
    alg, jac = m.function("alg"), m.function("dae_jac")
    for _ in range(50):
        g = np.array(alg(x, z, u, p)).ravel()
        if np.max(np.abs(g), initial=0) < 1e-14:
            break
        z = z - np.linalg.solve(np.array(jac(x, z, u, p)[3]), g)
    ode = np.array(m.function("ode")(x, z, u, p)).ravel()
    sig = np.array(m.function("signals")(x, z, u, p)).ravel()
    return ode, sig[m.signal_names.index(L)]


@pytest.mark.parametrize("fidelity", ["full", "static_chain"])
def test_matrices_match_central_differences(fidelity):
    m = hanging_load(1, load_kg=0.02, fidelity=fidelity)
    op = operating_point(m, {P: 5e4})
    sys = linearize(m, op, [L])
    xs, us = m.nominal("x"), np.array([1e3])
    cols = []
    for vec, scale in (("x", xs), ("u", us)):
        base = op.x if vec == "x" else op.u
        for i in range(len(base)):
            h = 1e-6 * scale[i]
            plus, minus = base.copy(), base.copy()
            plus[i] += h
            minus[i] -= h
            args = [(plus, op.u), (minus, op.u)] if vec == "x" else [(op.x, plus), (op.x, minus)]
            fp, fm = (np.concatenate(_reduced(m, x, u, op.p, op.z), axis=None) for x, u in args)
            cols.append((fp - fm) / (2 * h))
    fd = np.array(cols).T  # rows: ode..., length; columns: x..., u
    exact = np.block([[sys.A, sys.B], [sys.C, sys.D]])
    scale = np.maximum(np.abs(exact).max(axis=1, keepdims=True), 1e-30)
    assert np.max(np.abs(fd - exact) / scale) < 1e-5
    if fidelity == "static_chain":
        assert m.nz == 1  # the algebraic unknown really was eliminated


def test_one_percent_step_matches_nonlinear(plant):
    m, op = plant
    du = 0.01 * op.u[0]
    t = np.arange(0, 1.0 + 1e-12, 0.005)
    sim = Simulator(m)
    sim.reset(x0=op.x, z0=op.z)
    X, Z, U = sim.advance({P: op.u[0] + du}, t)
    y_nl = _length(m, X, Z, U, op.p)
    sys = linearize(m, op, [L])
    y_lin = ct.forced_response(sys, t, np.full_like(t, du)).outputs
    step = y_nl[-1] - op[L]
    assert abs(step) > 1e-5  # a real response: 0.4 mm
    assert np.max(np.abs((y_nl - op[L]) - y_lin)) < 0.01 * abs(step)


def test_frequency_response_matches_bode(plant):
    """Small sines on the nonlinear model: gain and phase of the length at the input's
    frequency (a least-squares fit over whole periods after the transient)."""
    m, op = plant
    sys = linearize(m, op, [L])
    first_resonance = min(r["frequency_Hz"] for r in classify_poles(m, sys) if r["imag_1_s"])
    freqs = [0.5, 2.0, 5.0]
    assert max(freqs) < first_resonance / 4
    amp = 0.01 * op.u[0]
    for f in freqs:
        periods_settle, periods_fit = 3, 2
        t = np.arange(0, (periods_settle + periods_fit) / f, 1 / (f * 50))
        sim = Simulator(m)
        sim.reset(x0=op.x, z0=op.z)
        X, Z, U = sim.advance({P: Sine(amplitude=amp, frequency=f, offset=op.u[0])}, t)
        y = _length(m, X, Z, U, op.p)
        keep = t >= periods_settle / f
        w = 2 * np.pi * f
        basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])[keep]
        a, b, _ = np.linalg.lstsq(basis, y[keep], rcond=None)[0]
        gain, phase = np.hypot(a, b) / amp, np.arctan2(b, a)
        resp = ct.frequency_response(sys, [w])
        g_lin = float(np.abs(resp.complex).ravel()[0])
        ph_lin = float(np.angle(resp.complex).ravel()[0])
        assert gain == pytest.approx(g_lin, rel=0.02)
        assert np.angle(np.exp(1j * (phase - ph_lin))) == pytest.approx(0, abs=0.02)


def test_python_control_tools_run(plant):
    m, op = plant
    sys = linearize(m, op, [L])
    poles = ct.poles(sys)
    assert np.all(poles.real < 0) and len(poles) == m.nx
    A, B, C, D = sys.A, sys.B, sys.C, sys.D
    # transmission zeros: the finite generalised eigenvalues of the Rosenbrock pencil
    n = m.nx
    pencil = sla.eigvals(np.block([[A, B], [C, D]]), sla.block_diag(np.eye(n), np.zeros((1, 1))))
    finite = np.sort_complex(pencil[np.isfinite(pencil) & (np.abs(pencil) < 1e12)])
    np.testing.assert_allclose(np.sort_complex(ct.zeros(sys)), finite, rtol=1e-6)
    resp = ct.step_response(sys, np.linspace(0, 1, 201))
    dc = float((D - C @ np.linalg.solve(A, B))[0, 0])  # G(0) = D - C A^-1 B
    assert sys.dcgain() == pytest.approx(dc, rel=1e-9)
    assert resp.outputs[-1] == pytest.approx(dc, rel=1e-3)
    w = np.logspace(0, 3, 20)
    resp = ct.frequency_response(sys, w)
    G = [(C @ np.linalg.solve(1j * wk * np.eye(n) - A, B) + D)[0, 0] for wk in w]
    np.testing.assert_allclose(np.ravel(resp.magnitude), np.abs(G), rtol=1e-9)
    lines = ct.bode_plot(resp)
    assert lines.shape[0] == 2  # magnitude and phase axes
    plt.close("all")
    Q, R = np.diag(1 / m.nominal("x") ** 2), np.eye(1) / 1e8
    K, _, E = ct.lqr(sys, Q, R)
    S = sla.solve_continuous_are(A, B, Q, R)  # independent Riccati solution
    np.testing.assert_allclose(K, np.linalg.solve(R, B.T @ S), rtol=1e-6)
    np.testing.assert_allclose(
        np.sort_complex(E), np.sort_complex(sla.eigvals(A - B @ K)), rtol=1e-8
    )
    assert np.all(E.real < 0)
    assert [from_label(s) for s in sys.state_labels] == m.state_names


def test_zoh_discretisation_is_the_matrix_exponential(plant):
    m, op = plant
    dt = 0.01
    c, d = linearize(m, op, [L]), linearize(m, op, [L], dt=dt)
    n = m.nx
    M = sla.expm(np.block([[c.A, c.B], [np.zeros((1, n + 1))]]) * dt)
    assert d.dt == dt
    np.testing.assert_allclose(d.A, M[:n, :n], atol=1e-9)
    np.testing.assert_allclose(d.B, M[:n, n:], rtol=1e-9, atol=1e-20)
    with pytest.raises(ParameterError, match="'dt'"):
        linearize(m, op, [L], dt=0.0)


def test_operating_point_by_load_and_by_target():
    m = hanging_load(1, load_kg=0.0)
    heavy = operating_point(m, {P: 3e4}, load_kg=0.05)
    light = operating_point(m, {P: 3e4})
    assert heavy[L] > light[L]  # the 50 g pull the chain longer
    goal = light[L] - 1e-3
    op = operating_point(m, target=(L, goal))
    assert op[L] == pytest.approx(goal, abs=1e-9)
    assert op.u[0] > 3e4
    # an independent check: the found input, solved again from scratch, gives the length
    again = operating_point(m, {P: float(op.u[0])})
    assert again[L] == pytest.approx(goal, abs=1e-9)
    with pytest.raises(ParameterError, match=r"target\.myofibril\.length"):
        operating_point(m, target=(L, 1.0))
    with pytest.raises(ParameterError, match="load_kg"):
        operating_point(m, load_kg=-0.01)


def test_poles_named_by_physics():
    m = hanging_load(3, load_kg=0.02)
    sys = linearize(m, operating_point(m, {P: 5e4}), [L])
    rows = classify_poles(m, sys)
    modes = {r["mode"] for r in rows}
    assert modes == {"pressure", "expansion", "body", "load"}
    reg = [r for r in rows if r["dominant_state"] == "regulator.p_set"]
    assert reg[0]["real_1_s"] == pytest.approx(-1 / 0.05)  # the regulator's 50 ms lag
    load = [r for r in rows if r["mode"] == "load"]
    assert len(load) == 1 and load[0]["imag_1_s"] > 0  # one oscillating load mode
    eig = np.linalg.eigvals(sys.A)
    assert sum(1 if r["imag_1_s"] == 0 else 2 for r in rows) == len(eig)
