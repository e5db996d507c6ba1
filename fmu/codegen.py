"""The physics of an FMU: CasADi Functions of the flattened model, generated to C.

Every Function here is built from :class:`~sarcomere.dynamics.modeling.model.Model`'s own
expressions, from :func:`~sarcomere.dynamics.equilibrium.newton_function` or from
:func:`~sarcomere.dynamics.simulation.radau.c_functions`; nothing is written twice. The
generated file ``sm_casadi.c`` holds (all ``nz = 0``):

=========== ============================ ===========================================
Function    arguments -> results         job
=========== ============================ ===========================================
sm_ode      x, u, p -> xdot              Model Exchange derivatives
sm_out      x, u, p -> y                 the declared outputs
sm_fwd      x, u, p, dx, du -> dxdot, dy forward directional derivatives (``jtimes``)
sm_eq       x0, u, p -> x, residual      equilibrium Newton (``fast_newton``)
=========== ============================ ===========================================

The Co-Simulation step is the simulator's own adaptive Radau IIA (``radau``): its C
source ``dynamics/simulation/c/radau.c`` (``sm_radau``: RADAU5's simplified Newton,
embedded error estimate and step-size control) is copied into the FMU's sources, with
``sm_rhs`` and ``sm_jac`` ``(t, xi, w, p)`` (``radau.c_functions`` under the held input
law, ``w = u``: the inputs are held over a communication step; in the states over their
nominal values, :func:`scaled_radau_functions`) generated into ``sm_radau_model.c``
(``casadi_int`` = ``int``, as ``radau.c`` declares them), and ``sm_radau.h``: the
method's constants (:func:`~sarcomere.dynamics.simulation.collocation.radau5_packed`),
the states' scale, tolerances and limits. Each ``doStep`` restarts the integrator from
``(t, x)`` (automatic first step, fresh Jacobian), so a saved FMU state (``t``, ``x``,
``u``, ``p``) is all it needs.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import newton_function
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.simulation import radau
from sarcomere.dynamics.simulation.collocation import radau5_packed
from sarcomere.dynamics.simulation.common import HELD

CS_RTOL = 1e-8
"""Relative tolerance of a Co-Simulation ``doStep`` when the importer defines none
(FMI 2 ``setupExperiment``, FMI 3 ``enterInitializationMode``) [-]."""

CS_ATOL_PER_RTOL = 1e-2
"""Absolute tolerance per unit of relative tolerance and of nominal value [-]: state ``i``
has ``atol_i = CS_ATOL_PER_RTOL * rtol * nominal_i`` (the integrator works in ``x /
nominal``; :func:`scaled_radau_functions`): 1e-10 m/s for a velocity (nominal 1 m/s),
5e-16 kg for a chamber's air (nominal 4.8e-6 kg) at the default rtol. Not tighter:
``radau.c``'s Newton iteration fails at atol 1e-12 m/s with rtol 1e-8 on vent-0g (10 ms
steps from its equilibrium: the velocities rest at 0), natively as in the FMU (issue 17,
radau at tight absolute tolerances)."""

CS_ATOL_MIN = 1e-10
"""The smallest absolute tolerance, per unit of nominal value [-]: an importer's rtol
below 1e-8 tightens the relative tolerance only. ``radau.c``'s Newton iteration fails
below it on resting states (at rtol 1e-10 with atol 1e-12 x nominal, 10 ms steps from
rest on step-50g and vent-0g; issue 17)."""

CS_RTOL_RANGE = (1e-12, 1e-2)
"""The relative tolerances an importer may set [-]; others are refused at set-up."""

CS_MAX_STEPS = 100_000
"""Most internal Radau IIA steps of one ``doStep``; more is an error naming the time."""

CS_MAX_NEWTON = 7
"""Newton iterations per Radau IIA step attempt (RADAU5's default)."""

EQ_NEWTON_ITERATIONS = 30
"""Newton iterations of one equilibrium solve (one continuation step) in C."""

CFLAGS = tuple(f for f in radau.CFLAGS if f.startswith("-f"))
"""The integrator's code-generation flags (``radau.CFLAGS`` without the optimisation
level and standard, which the FMU's compile sets): inline complex arithmetic."""

RADAU_FUNCTIONS = ("sm_rhs", "sm_jac", "sm_x_scale")
"""The Functions ``radau.c`` calls (generated into ``sm_radau_model.c``) and the states'
scale they take (written into ``sm_radau.h``)."""


@dataclass(frozen=True)
class Generated:
    """The work sizes the wrapper allocates for the generated functions of ``sm_casadi.c``
    (the largest) and the generated C files to compile."""

    sz_arg: int
    sz_res: int
    sz_iw: int
    sz_w: int
    sources: tuple[str, ...] = ("sm_casadi.c",)


def require_ode(model: Model) -> None:
    """Refuse a model with algebraic unknowns (the FMU integrates an explicit ODE)."""
    if model.nz:
        raise ParameterError(
            "model",
            model.name,
            "a model without algebraic unknowns (nz = 0: fidelity 'full', 'quasi_static' "
            "or 'symmetric')",
            f"it has {model.nz}",
        )


def functions(model: Model) -> list[cs.Function]:
    """The Functions of the module docstring, in that order, then those of
    :func:`scaled_radau_functions`."""
    require_ode(model)
    m = model
    x, u, p = m.x, m.u, m.p
    nothing = cs.SX(0, 1)
    ode = m.function("ode")(x, nothing, u, p)
    y = m.function("y")(x, nothing, u, p)
    dx, du = cs.SX.sym("dx", m.nx), cs.SX.sym("du", u.numel())
    xu, dxu = cs.vertcat(x, u), cs.vertcat(dx, du)
    fwd = [cs.jtimes(ode, xu, dxu), cs.jtimes(y, xu, dxu)]
    newton = newton_function(m, EQ_NEWTON_ITERATIONS)
    x0 = cs.MX.sym("x0", m.nx)
    um, pm = cs.MX.sym("u", u.numel()), cs.MX.sym("p", p.numel())
    eq = newton(x0, cs.MX(0, 1), um, pm)
    return [
        cs.Function("sm_ode", [x, u, p], [ode], ["x", "u", "p"], ["xdot"]),
        cs.Function("sm_out", [x, u, p], [y], ["x", "u", "p"], ["y"]),
        cs.Function("sm_fwd", [x, u, p, dx, du], fwd, ["x", "u", "p", "dx", "du"], ["dxdot", "dy"]),
        cs.Function("sm_eq", [x0, um, pm], [eq[0], eq[2]], ["x0", "u", "p"], ["x", "residual"]),
        *scaled_radau_functions(m),
    ]


def scaled_radau_functions(model: Model) -> tuple[cs.Function, cs.Function, cs.Function]:
    """``sm_rhs`` and ``sm_jac`` of ``radau.c_functions`` (inputs held) in the scaled
    states ``xi = x / s``, ``s`` = the states' nominal values (:func:`state_scale`): the
    integrator's scalar atol is then ``atol * s_i`` in each state's own unit; and
    ``sm_x_scale() -> s``, which :func:`generate` writes into ``sm_radau.h`` (not
    generated code: the scale travels with the Functions built on it)."""
    rhs, jac = radau.c_functions(model, HELD)
    s = state_scale(model)
    t, xi = cs.SX.sym("t"), cs.SX.sym("xi", model.nx)
    w, p = cs.SX.sym("w", rhs.size1_in(2)), cs.SX.sym("p", rhs.size1_in(3))
    x = cs.DM(s) * xi
    f = rhs(t, x, w, p) / cs.DM(s)
    J = jac(t, x, w, p) * cs.DM(s[None, :] / s[:, None])
    return (
        cs.Function("sm_rhs", [t, xi, w, p], [cs.cse(f)]),
        cs.Function("sm_jac", [t, xi, w, p], [cs.cse(cs.densify(J))]),
        cs.Function("sm_x_scale", [], [cs.DM(s)]),
    )


def state_scale(model: Model) -> np.ndarray:
    """The states' scales of the Co-Simulation integrator [SI]: their nominal values (as
    the FMU declares them; fmpy's CVode takes ``atol = rtol * nominal`` from those in
    Model Exchange)."""
    return np.asarray(model.nominal("x"), dtype=float)


def generate(funcs: list[cs.Function], folder: Path) -> Generated:
    """Write ``funcs`` (e.g. :func:`functions`) as C into ``folder``: ``sm_casadi.c`` and
    ``sm_casadi.h``, and, when :data:`RADAU_FUNCTIONS` are among them, the integrator
    (module docstring); the work sizes are the largest over ``sm_casadi.c``'s Functions."""
    folder = Path(folder)
    own = [f for f in funcs if f.name() not in RADAU_FUNCTIONS]
    gen = cs.CodeGenerator("sm_casadi.c", {"with_header": True, "casadi_int": "long long int"})
    for f in own:
        gen.add(f)
    gen.generate(f"{folder}/")
    sources = ("sm_casadi.c",)
    integrator = [f for f in funcs if f.name() in RADAU_FUNCTIONS]
    if integrator:
        if sorted(f.name() for f in integrator) != sorted(RADAU_FUNCTIONS):
            raise ParameterError("functions", "incomplete", f"all of {RADAU_FUNCTIONS} or none")
        rgen = cs.CodeGenerator("sm_radau_model.c", {"casadi_int": "int"})
        by_name = {f.name(): f for f in integrator}
        for name in RADAU_FUNCTIONS[:2]:
            rgen.add(by_name[name])
        rgen.generate(f"{folder}/")
        shutil.copyfile(radau.SOURCE, folder / "radau.c")
        scale = np.array(by_name["sm_x_scale"]()["o0"]).ravel()
        (folder / "sm_radau.h").write_text(radau_header(scale))
        sources += ("sm_radau_model.c", "radau.c")
    return Generated(
        max(f.sz_arg() for f in own),
        max(f.sz_res() for f in own),
        max(f.sz_iw() for f in own),
        max(f.sz_w() for f in own),
        sources,
    )


def radau_header(scale: np.ndarray) -> str:
    """``sm_radau.h``: the integrator's constants, the states' scale, tolerances, limits
    and entry point."""
    values = ",\n    ".join(repr(float(v)) for v in radau5_packed())
    scales = ",\n    ".join(repr(float(v)) for v in scale)
    return f"""/* Generated by sarcomere: the Co-Simulation's adaptive Radau IIA (radau.c). */
#ifndef SM_RADAU_H
#define SM_RADAU_H

#define SM_RTOL {CS_RTOL!r}
#define SM_ATOL_PER_RTOL {CS_ATOL_PER_RTOL!r}
#define SM_ATOL_MIN {CS_ATOL_MIN!r}
#define SM_RTOL_MIN {CS_RTOL_RANGE[0]!r}
#define SM_RTOL_MAX {CS_RTOL_RANGE[1]!r}
#define SM_RADAU_MAX_STEPS {CS_MAX_STEPS}L
#define SM_RADAU_MAX_NEWTON {CS_MAX_NEWTON}
#define SM_RADAU_STATS 32 /* room for radau.c's statistics counters (ST_N, 7 today) */

/* The method constants in radau.c's Tableau order (collocation.radau5_packed). */
static const double sm_radau_tableau[{len(radau5_packed())}] = {{
    {values}
}};

/* The states' scale: sm_rhs and sm_jac take x / sm_radau_scale (codegen.state_scale). */
static const double sm_radau_scale[{len(scale)}] = {{
    {scales}
}};

/* radau.c's entry point: integrate x' = sm_rhs(t, x, w, p) from t0 to tout[nout - 1]. */
int sm_radau(int n, const double* w, const double* p, double t0, double* x, int nout,
             const double* tout, double* xout, const double* cst, const double* opt,
             long max_steps, int max_newton, double* stats, double* t_fail);

#endif
"""
