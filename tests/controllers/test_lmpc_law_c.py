"""The LMPC's law as generated C: compiled with DAQP linked statically from the CasADi
wheel (:func:`~sarcomere.controllers.rti_compiled.daqp_build`), it is a self-contained
library giving the Python LMPC's commands and memory exactly."""

import subprocess

import casadi as cs
import numpy as np

from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.rti_compiled import daqp_build
from sarcomere.dynamics import hanging_load, solve_equilibrium
from sarcomere.dynamics.simulation.compiled import compiler

P = "regulator.p_cmd"
L = "myofibril.length"


def test_the_compiled_daqp_law_is_the_python_lmpc(tmp_path):
    model = hanging_load(1, load_kg=0.02)
    eq = solve_equilibrium(model, {P: 5e4})
    soft = (("myofibril.actin0.T", 0.0), ("myofibril.actin1.T", 0.0))
    mpc = LinearMPC(model, eq.x, eq.u, 0.01, LMPCSettings(soft_min=soft, horizon=10))
    gen = cs.CodeGenerator("lmpc_law.c")
    gen.add(mpc.law_function())
    gen.generate(f"{tmp_path}/")
    src, lib = tmp_path / "lmpc_law.c", tmp_path / "lmpc_law.so"
    flags, link = daqp_build()
    cmd = [compiler(), "-O2", "-fPIC", "-shared", str(src), "-o", str(lib), *flags, *link, "-lm"]
    subprocess.run(cmd, check=True, capture_output=True)
    nm = ["nm", "-D", "--undefined-only", str(lib)]
    undefined = subprocess.run(nm, capture_output=True, text=True, check=True).stdout
    assert "daqp" not in undefined  # DAQP is inside the library
    law = cs.external("lmpc", str(lib))
    y = {n: eq[n] for n in mpc.outputs}
    for k in range(5):
        ref = eq[L] - 1e-3 * (k + 1) / 5
        memory, u_prev = mpc.memory, mpc._u.copy()
        x = [*eq.x, y[L], *(y[n] for n, _ in soft)]
        u = mpc.checked(0.01 * k, y, {L: ref})[P]
        mem_c, u_c, ok = law(memory, x, u_prev, np.full(11, ref), mpc.law_parameters())
        assert bool(ok) and float(u_c) == u
        assert np.array_equal(np.array(mem_c).ravel(), mpc.memory)
    assert u > 5e4 + 1e3  # it moved
