"""DAE-aware linearisation: exact A, B, C, D against central finite differences of the
nonlinear model (z re-solved by Newton after each perturbation), and its generated C."""

import shutil
import subprocess

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

U = {"regulator.p_cmd": 3e4}


@pytest.fixture(scope="module")
def dae():
    return hanging_load(n=2, load_kg=0.05, fidelity="static_chain")


@pytest.fixture(scope="module")
def ode():
    return hanging_load(n=2, load_kg=0.05)


def consistent_z(model, x, z, u, p):
    """Newton on g(x, z, u, p) = 0 for z."""
    g, jac = model.function("alg"), model.function("dae_jac")
    z = np.array(z, dtype=float)
    for _ in range(50):
        r = np.array(g(x, z, u, p)).ravel()
        dz = np.linalg.solve(np.array(jac(x, z, u, p)[3]), -r)
        z = z + dz
        if np.max(np.abs(dz) / np.maximum(np.abs(z), 1e-12)) < 1e-15:
            return z
    raise AssertionError("Newton for z did not converge")


def finite_differences(model, names, x, z, u, p):
    """Central differences of (ode, signals[names]) in x and u, with z re-solved."""
    rows = [model.signal_names.index(n) for n in names]
    f, sig = model.function("ode"), model.function("signals")

    def evaluate(xx, uu):
        zz = consistent_z(model, xx, z, uu, p) if model.nz else z
        return np.concatenate(
            [np.array(f(xx, zz, uu, p)).ravel(), np.array(sig(xx, zz, uu, p))[rows, 0]]
        )

    cols = []
    for vec, nom in ((x, model.nominal("x")), (u, model.nominal("u"))):
        for j in range(vec.size):
            h = 1e-6 * max(abs(vec[j]), 1e-3 * nom[j])
            plus, minus = vec.copy(), vec.copy()
            plus[j] += h
            minus[j] -= h
            if vec is x:
                cols.append((evaluate(plus, u) - evaluate(minus, u)) / (2 * h))
            else:
                cols.append((evaluate(x, plus) - evaluate(x, minus)) / (2 * h))
    J = np.column_stack(cols)
    nx = model.nx
    return J[:nx, :nx], J[:nx, nx:], J[nx:, :nx], J[nx:, nx:]


def scaled_error(exact, approx):
    """Largest difference relative to the largest entry of its row (rows in own units)."""
    exact, approx = np.asarray(exact), np.asarray(approx)
    scale = np.maximum(np.max(np.abs(exact), axis=1, keepdims=True), 1e-300)
    return float(np.max(np.abs(exact - approx) / scale))


def off_equilibrium_point(model):
    eq = solve_equilibrium(model, U)
    # 1 % off the equilibrium in every state (of 1e-3 x its nominal value where it is ~0)
    sign = np.where(np.arange(model.nx) % 2, 1.0, -1.0)
    x = eq.x + sign * 0.01 * np.maximum(np.abs(eq.x), 1e-3 * model.nominal("x"))
    z = consistent_z(model, x, eq.z, eq.u, eq.p) if model.nz else eq.z
    return x, z, eq.u, eq.p


def check_against_finite_differences(model, names):
    x, z, u, p = off_equilibrium_point(model)
    lin = model.linearization(names)(x=x, z=z, u=u, p=p)
    fd = finite_differences(model, names, x, z, u, p)
    errors = [scaled_error(lin[k], ref) for k, ref in zip("ABCD", fd, strict=True)]
    assert max(errors) < 1e-6, errors
    return x, z, u, p, lin


def test_explicit_ode_linearisation_matches_finite_differences(ode):
    names = ["load.s", "myofibril.aps1.chamber.p", "regulator.p_cmd", "myofibril.length"]
    assert ode.nz == 0
    check_against_finite_differences(ode, names)


def test_dae_linearisation_eliminates_z_and_matches_finite_differences(dae):
    names = [
        "load.s",  # a state
        "myofibril.actin1.flange_a.s",  # an algebraic unknown kept in z
        "myofibril.aps1.chamber.flange.f",  # a solved variable
        "regulator.p_cmd",  # an input
        "myofibril.length",  # a declared output
    ]
    assert dae.nz > 0 and names[1] in dae.alg_names
    x, z, u, p, lin = check_against_finite_differences(dae, names)
    # "jac" is the same elimination for the declared outputs, not d ode/dx at fixed z
    jac = dae.function("jac")(x=x, z=z, u=u, p=p)
    np.testing.assert_allclose(np.array(jac["A"]), np.array(lin["A"]), rtol=1e-12, atol=0)
    naive = np.array(dae.function("dae_jac")(x=x, z=z, u=u, p=p)["ode_x"])
    assert scaled_error(lin["A"], naive) > 1e-2


def test_an_unknown_signal_is_a_parameter_error(dae):
    with pytest.raises(ParameterError, match=r"parameter 'outputs' = 'load\.q' is invalid"):
        dae.linearization(["load.s", "load.q"])


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_dae_linearisation_generates_c_that_gives_the_same_numbers(dae, tmp_path):
    names = ["load.s", "myofibril.length"]
    F = dae.linearization(names)
    F.generate("lin.c", {"with_header": True})
    shutil.move("lin.c", tmp_path / "lin.c")
    shutil.move("lin.h", tmp_path / "lin.h")
    lib = tmp_path / "lin.so"
    subprocess.run(
        [
            "gcc",
            "-shared",
            "-fPIC",
            "-O1",
            "-Wall",
            "-Werror=implicit-function-declaration",
            str(tmp_path / "lin.c"),
            "-o",
            str(lib),
        ],
        check=True,
    )
    C = cs.external(F.name(), str(lib))
    x, z, u, p = off_equilibrium_point(dae)
    for a, b in zip(C(x, z, u, p), F(x, z, u, p), strict=True):
        np.testing.assert_allclose(np.array(a), np.array(b), rtol=1e-13, atol=0)
