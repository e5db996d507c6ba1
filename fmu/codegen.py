"""The physics of an FMU: CasADi Functions of the flattened model, generated to C.

Every Function here is built from :class:`~sarcomere.dynamics.modeling.model.Model`'s own
expressions or from :func:`~sarcomere.dynamics.equilibrium.newton_function`; nothing is
written twice. The generated file ``sm_casadi.c`` holds (all ``nz = 0``):

=========== ============================ ===========================================
Function    arguments -> results         job
=========== ============================ ===========================================
sm_ode      x, u, p -> xdot              Model Exchange derivatives
sm_out      x, u, p -> y                 the declared outputs
sm_fwd      x, u, p, dx, du -> dxdot, dy forward directional derivatives (``jtimes``)
sm_eq       x0, u, p -> x, residual      equilibrium Newton (``fast_newton``)
sm_step     x0, u, p, h -> xf, residual  one Radau IIA step (Co-Simulation)
=========== ============================ ===========================================

``sm_step`` is one step of Radau IIA with :data:`RADAU_POINTS` points (order 5,
L-stable) solved by ``fast_newton`` in scaled stage increments ``w_j = (x_j - x0) / s``,
``s = max(|x0|, nominal)``; ``residual`` [-] is the infinity norm of the scaled
collocation residual at the returned point, which the C wrapper compares with its
tolerance (a step that fails it is halved).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import newton_function
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

RADAU_POINTS = 3
"""Radau IIA points of the Co-Simulation step (3: order 5, stiffly accurate, L-stable)."""

STEP_NEWTON_ITERATIONS = 8
"""Most Newton iterations of one Radau step; ``fast_newton`` stops earlier once the scaled
residual is below :data:`STEP_NEWTON_TOL`."""

STEP_NEWTON_TOL = 1e-10
"""Scaled residual at which ``fast_newton`` stops iterating a Radau step [-]."""

EQ_NEWTON_ITERATIONS = 30
"""Newton iterations of one equilibrium solve (one continuation step) in C."""


@dataclass(frozen=True)
class Generated:
    """The work sizes the wrapper allocates for the generated functions (the largest)."""

    sz_arg: int
    sz_res: int
    sz_iw: int
    sz_w: int


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
    """The Functions of the module docstring, in that order."""
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
        radau_step(m),
    ]


def radau_step(model: Model, points: int = RADAU_POINTS) -> cs.Function:
    """One Radau IIA step ``(x0, u, p, h) -> (xf, residual)`` (see the module docstring)."""
    m = model
    nx = m.nx
    x0, u, p, h = cs.SX.sym("x0", nx), cs.SX.sym("u", m.u.numel()), m.p, cs.SX.sym("h")
    s = cs.fmax(cs.fabs(x0), cs.DM(m.nominal("x")))
    tau = cs.collocation_points(points, "radau")
    C = np.array(cs.collocation_coeff(tau)[0])  # (points + 1) x points
    W = cs.SX.sym("w", nx, points)
    f = cs.Function("f", [m.x, m.u, m.p], [m.function("ode")(m.x, cs.SX(0, 1), m.u, m.p)])
    res = []
    for j in range(points):
        # d/dtau of the interpolating polynomial through (0, 0), (tau_r, w_r) at tau_j
        slope = sum(C[r + 1, j] * W[:, r] for r in range(points))
        res.append(slope - h * f(x0 + s * W[:, j], u, p) / s)
    args = cs.vertcat(x0, u, p, h)
    g = cs.Function("g", [cs.vec(W), args], [cs.vertcat(*res)])
    opts = {
        "max_iter": STEP_NEWTON_ITERATIONS,
        "abstol": STEP_NEWTON_TOL,
        "abstolStep": 0.0,
        "error_on_fail": False,
    }
    solve = cs.rootfinder("radau_newton", "fast_newton", g, opts)
    x0m, um, pm, hm = (
        cs.MX.sym(n, v.numel()) for n, v in (("x0", x0), ("u", u), ("p", p), ("h", h))
    )
    argm = cs.vertcat(x0m, um, pm, hm)
    wf = solve(cs.MX(nx * points, 1), argm)
    resid = cs.mmax(cs.fabs(g(wf, argm)))
    sm = cs.fmax(cs.fabs(x0m), cs.DM(m.nominal("x")))
    xf = x0m + sm * wf[nx * (points - 1) :]
    return cs.Function(
        "sm_step", [x0m, um, pm, hm], [xf, resid], ["x0", "u", "p", "h"], ["xf", "residual"]
    )


def generate(funcs: list[cs.Function], folder: Path) -> Generated:
    """Write ``funcs`` (e.g. :func:`functions`) as ``sm_casadi.c`` and ``sm_casadi.h`` into
    ``folder``; the work sizes are the largest over the Functions."""
    gen = cs.CodeGenerator("sm_casadi.c", {"with_header": True, "casadi_int": "long long int"})
    for f in funcs:
        gen.add(f)
    folder = Path(folder)
    gen.generate(f"{folder}/")
    return Generated(
        max(f.sz_arg() for f in funcs),
        max(f.sz_res() for f in funcs),
        max(f.sz_iw() for f in funcs),
        max(f.sz_w() for f in funcs),
    )
