"""Generated Python source equals the CasADi Function it came from."""

import subprocess
import sys

import casadi as cs
import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.simulation.simulate import SolverSettings, simulate
from sarcomere.dynamics.studies.pysource import python_function, python_source, register_baseline


def test_model_rhs_and_jacobian_agree_with_casadi():
    m = hanging_load(2, load_kg=0.02)
    eq = solve_equilibrium(m, {"regulator.p_cmd": 0.04e6})
    rng = np.random.default_rng(3)
    for F in (m.function("ode"), m.function("jac")):
        f = python_function(F)
        for _ in range(5):
            x = eq.x * (1 + 0.01 * rng.standard_normal(m.nx))
            u = np.array([rng.uniform(0, 1e5)])
            ref = [np.array(v.nonzeros()) for v in F.call([x, [], u, eq.p])]
            got = f(x, [], u, eq.p)
            for a, b in zip(ref, got, strict=True):
                np.testing.assert_allclose(b, a, rtol=1e-13, atol=1e-300)


def test_ieee_semantics_where_casadi_evaluates_both_branches():
    x = cs.SX.sym("x")
    F = cs.Function("g", [x], [cs.if_else(x > 0, cs.sqrt(x) / x, 0.0)])
    f = python_function(F)
    assert f([0.0])[0][0] == 0.0  # 0/0 and sqrt(-0) in the unused branch do not raise
    assert f([4.0])[0][0] == pytest.approx(0.5)


def test_source_is_straight_line_python():
    x = cs.SX.sym("x", 2)
    src = python_source(cs.Function("h", [x], [x[0] * x[1] + 1]))
    assert src.startswith("def h(i0):") and "for " not in src


def test_scipy_radau_on_the_python_rhs_matches_cvodes():
    assert register_baseline() == "scipy_radau_numpy"
    m = hanging_load(1, load_kg=0.05)
    eq = solve_equilibrium(m, {"regulator.p_cmd": 0.0})
    runs = [
        simulate(
            m,
            0.5,
            {"regulator.p_cmd": 5e4},
            x0=eq.x,
            signals=["myofibril.length"],
            settings=SolverSettings(method=meth, rtol=1e-8, atol=1e-11),
        )
        for meth in ("cvodes", "scipy_radau_numpy")
    ]
    np.testing.assert_allclose(runs[1]["myofibril.length"], runs[0]["myofibril.length"], rtol=1e-6)


def test_importing_the_studies_registers_no_method():
    """The baseline is registered on request (``register_baseline``), never as a side
    effect of an import: a fresh interpreter importing the studies sees the library's
    methods only."""
    code = (
        "import sarcomere.dynamics.studies.workprecision, sarcomere.dynamics.studies.stability\n"
        "from sarcomere.dynamics.simulation.settings import METHODS\n"
        "import sarcomere.dynamics.simulation.simulate\n"
        "print('scipy_radau_numpy' in METHODS, 'scipy_radau' in METHODS)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True"]
