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


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_right_hand_side_and_jacobian_generate_self_contained_c(model, tmp_path):
    """What FMU export will need: plain C from the same Functions (libc and libm only)."""
    cg = cs.CodeGenerator("sarcomere_model.c", {"with_header": True})
    cg.add(model.function("ode"))
    cg.add(model.function("jac"))
    cg.add(model.function("y"))
    cg.generate(str(tmp_path) + "/")
    obj = tmp_path / "model.o"
    subprocess.run(
        [
            "gcc",
            "-c",
            "-O1",
            "-Wall",
            "-Werror=implicit-function-declaration",
            str(tmp_path / "sarcomere_model.c"),
            "-o",
            str(obj),
        ],
        check=True,
    )
    assert obj.stat().st_size > 1000
