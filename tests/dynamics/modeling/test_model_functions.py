"""The flattened model's CasADi Functions: named, consistent, and ready for codegen."""

import shutil
import subprocess

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load


@pytest.fixture(scope="module")
def model():
    return hanging_load(2, load_kg=0.05)


def test_functions_have_named_inputs_and_outputs(model):
    f = model.function("ode")
    assert f.name_in() == ["x", "z", "u", "p"] and f.name_out() == ["ode"]
    assert model.function("jac").name_out() == ["A", "B", "C", "D"]
    assert model.input_names == ["regulator.p_cmd"]
    assert "myofibril.length" in model.output_names
    assert all(model.unit(n) for n in model.state_names + model.output_names)


def test_linearisation_matrices_match_the_expressions(model):
    x, u, p = model.x0(), np.array([3e4]), model.parameters()
    J = model.function("jac")(x=x, z=[], u=u, p=p)
    A = cs.Function("a", [model.x, model.u, model.p], [cs.jacobian(model.ode, model.x)])
    np.testing.assert_allclose(np.array(J["A"]), np.array(A(x, u, p)))
    assert np.array(J["B"]).shape == (model.nx, 1)
    assert np.array(J["C"]).shape == (len(model.output_names), model.nx)


def _renamed(model, name: str) -> cs.Function:
    f = model.function(name)
    args = f.mx_in()
    return cs.Function(f"sm_{name}", args, f.call(args), f.name_in(), f.name_out())


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_right_hand_side_and_jacobian_generate_self_contained_c(model, tmp_path):
    """What FMU export will need: plain C from the same Functions (libc and libm only),
    which, compiled and loaded, gives the same numbers as the CasADi Functions."""
    cg = cs.CodeGenerator("sarcomere_model.c", {"with_header": True})
    names = ("ode", "jac", "y")
    for name in names:  # "jac" is reserved by casadi.external: prefixed in the C
        cg.add(_renamed(model, name))
    cg.generate(str(tmp_path) + "/")
    lib = tmp_path / "model.so"
    subprocess.run(
        [
            "gcc",
            "-shared",
            "-fPIC",
            "-O1",
            "-Wall",
            "-Werror=implicit-function-declaration",
            str(tmp_path / "sarcomere_model.c"),
            "-o",
            str(lib),
            "-lm",
        ],
        check=True,
    )
    x, u, p = model.x0(), np.array([3e4]), model.parameters()
    for name in names:
        compiled = cs.external(f"sm_{name}", str(lib))
        native = model.function(name)
        args = {"x": x, "z": [], "u": u, "p": p}
        got, want = compiled(**args), native(**args)
        assert set(got) == set(want)
        for key in want:
            np.testing.assert_allclose(
                np.array(got[key]), np.array(want[key]), rtol=1e-12, atol=0, err_msg=key
            )
