"""The equilibrium residual and its Newton solve as CasADi Functions (and their C), and
the input-name check of solve_equilibrium."""

import shutil
import subprocess

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import newton_function, residual_function, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError

U = {"regulator.p_cmd": 3e4}


@pytest.fixture(scope="module", params=["full", "static_chain"])
def case(request):
    model = hanging_load(2, load_kg=0.05, fidelity=request.param)
    return model, solve_equilibrium(model, U, tol=1e-14)  # a reference tighter than the gap


def relative_gap(model, x, eq):
    """Largest state difference relative to max(|x_eq|, 1e-3 nominal) (velocities are ~0)."""
    x = np.array(x).ravel()
    return np.max(np.abs(x - eq.x) / np.maximum(np.abs(eq.x), 1e-3 * model.nominal("x")))


def test_residual_function_is_ode_and_alg(case):
    model, eq = case
    x, z = 1.01 * eq.x, eq.z
    r, norm = residual_function(model)(x, z, eq.u, eq.p)
    expected = np.concatenate(
        [
            np.array(model.function(k)(x, z, eq.u, eq.p)).ravel()
            for k in ("ode", "alg")
            if model.function(k).size1_out(0)
        ]
    )
    np.testing.assert_array_equal(np.array(r).ravel(), expected)
    assert float(norm) > 1e-6  # off the equilibrium
    assert float(residual_function(model)(eq.x, eq.z, eq.u, eq.p)[1]) < 1e-10


def test_newton_function_matches_solve_equilibrium_from_a_nearby_start(case):
    model, eq = case
    out = newton_function(model)(x0=eq.x * (1 + 1e-3), z0=eq.z * (1 + 1e-3), u=eq.u, p=eq.p)
    assert float(out["residual"]) < 1e-10
    assert relative_gap(model, out["x"], eq) < 1e-9
    np.testing.assert_allclose(np.array(out["z"]).ravel(), eq.z, rtol=1e-9, atol=0)


def test_non_convergence_shows_in_the_residual_output(case):
    """fast_newton has no line search: 10 % off, full steps wander off, without an error."""
    model, eq = case
    out = newton_function(model)(x0=1.1 * eq.x, z0=1.1 * eq.z, u=eq.u, p=eq.p)
    assert float(out["residual"]) > 1e-3
    assert relative_gap(model, out["x"], eq) > 1e-2
    one = newton_function(model, iterations=1)(x0=1.001 * eq.x, z0=1.001 * eq.z, u=eq.u, p=eq.p)
    assert 1e-10 < float(one["residual"]) < 1.0


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_iterations_must_be_a_positive_integer(bad):
    with pytest.raises(ParameterError, match="parameter 'iterations'"):
        newton_function(hanging_load(1, load_kg=0.0), iterations=bad)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_newton_function_generates_c_that_gives_the_same_numbers(case, tmp_path, monkeypatch):
    model, eq = case
    F = newton_function(model)
    monkeypatch.chdir(tmp_path)
    F.generate("equilibrium.c", {"with_header": True})
    flags = ["-shared", "-fPIC", "-O1", "-Wall", "-Werror=implicit-function-declaration"]
    subprocess.run(["gcc", *flags, "equilibrium.c", "-o", "equilibrium.so", "-lm"], check=True)
    C = cs.external("equilibrium", str(tmp_path / "equilibrium.so"))
    args = (eq.x * (1 + 1e-3), eq.z * (1 + 1e-3), eq.u, eq.p)
    for a, b in zip(C(*args), F(*args), strict=True):
        np.testing.assert_allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-300)


def test_an_unknown_input_name_is_a_parameter_error():
    model = hanging_load(1, load_kg=0.0)
    with pytest.raises(
        ParameterError,
        match=r"^parameter 'inputs' = 'regulator\.p_cm' is invalid; allowed: an input of model "
        r"'hanging_n1_full': \['regulator\.p_cmd'\]$",
    ):
        solve_equilibrium(model, {"regulator.p_cm": 3e4})
    with pytest.raises(ParameterError, match="parameter 'inputs' = 'load.s'"):
        solve_equilibrium(model, {"load.s": 0.1})


def test_inputs_are_checked_and_take_units():
    """NaN or out-of-range inputs are refused (a NaN command once returned a finite
    equilibrium); a quantity string is converted like a parameter."""
    model = hanging_load(1, load_kg=0.05)
    for bad in (float("nan"), -1e4, 7e5):
        with pytest.raises(ParameterError, match=r"inputs\.regulator\.p_cmd"):
            solve_equilibrium(model, {"regulator.p_cmd": bad})
    a = solve_equilibrium(model, {"regulator.p_cmd": "0.05 MPa"})
    b = solve_equilibrium(model, {"regulator.p_cmd": 5e4})
    np.testing.assert_array_equal(a.x, b.x)
