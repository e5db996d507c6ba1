"""CasADi's SUNDIALS integrators: ``cvodes`` (explicit ODE) and ``idas`` (index-1 DAE).

The integrator runs in normalised time ``tau`` in [0, 1] over a segment ``[t0, t0 + H]``
(``t = t0 + H tau``, ``dx/dtau = H f``) with ``t0`` and ``H`` appended to the parameters,
and takes the input law's argument ``w`` as CasADi's piecewise-constant control ``u``
(constant over the segment, so CVODES integrates through the output points without
restarting). One integrator therefore serves every segment with the same relative output
grid: a closed loop of equal steps builds it once, whatever the time and step size.
"""

from __future__ import annotations

import re

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.model import Model
from .common import law_dae
from .settings import HELD, InputLaw, Segment, SolverSettings, add_stats, register_method


def integrator(
    model: Model, settings: SolverSettings, law: InputLaw, grid: tuple[float, ...]
) -> cs.Function:
    """The integrator ``F(x0, z0, p=[p; t0; H], u=w) -> xf, zf`` on the normalised
    ``grid`` (memoised on the model by plugin, settings, law and grid)."""
    plugin, s = settings.method, settings

    def build() -> cs.Function:
        d = law_dae(model, law)
        tau, t0, H = cs.SX.sym("tau"), cs.SX.sym("t0"), cs.SX.sym("H")
        ode, alg = cs.substitute([d.ode, d.alg], [d.t], [t0 + H * tau])
        dae = {"x": d.x, "u": d.w, "p": cs.vertcat(d.p, t0, H), "t": tau, "ode": H * ode}
        if model.nz:
            dae.update(z=d.z, alg=alg)
        opts = {
            "abstol": s.atol,
            "reltol": s.rtol,
            "max_num_steps": s.max_steps,
            "print_stats": False,
            "disable_internal_warnings": True,  # failures raise SolverError
            **dict(s.options),
        }
        try:
            return cs.integrator("F", plugin, dae, 0.0, list(grid), opts)
        except RuntimeError as exc:
            raise _refusal(plugin, "solver.options", dict(s.options), str(exc)) from None

    return model.cached(("sundials", settings.key, law.key(), grid), build)


def _check(model: Model, settings: SolverSettings) -> None:
    if settings.method == "cvodes" and model.nz:
        raise SolverError(
            f"cvodes needs an explicit ODE but model '{model.name}' keeps {model.nz} "
            "algebraic unknowns: use method 'idas'"
        )


def _run(seg: Segment) -> tuple[np.ndarray, np.ndarray]:
    m = seg.model
    _check(m, seg.settings)
    H = float(seg.times[-1] - seg.t0)
    tau = np.round((seg.times - seg.t0) / H, 12)
    tau[-1] = 1.0
    F = integrator(m, seg.settings, seg.law, tuple(tau.tolist()))
    W = np.repeat(seg.w[:, None], len(tau), axis=1)
    try:
        res = F(x0=seg.x0, z0=seg.z0, p=np.append(seg.p, (seg.t0, H)), u=W)
    except RuntimeError as exc:
        raise seg.fail(_cause(str(exc)), seg.t0, seg.x0) from None
    st = F.stats()
    add_stats(
        seg.stats,
        n_steps=int(st.get("nsteps", 0)),
        n_rhs=int(st.get("nfevals", 0)),
        n_jac=int(st.get("njevals", 0) or st.get("nlinsetups", 0)),
        n_segments=1,
    )
    X = np.array(res["xf"]).T
    Z = np.array(res["zf"]).T if m.nz else np.zeros((len(tau), 0))
    return X, Z


def step_function(model: Model, settings: SolverSettings) -> cs.Function:
    """``step(x, z, u, h, p) -> (xf, zf)``: one integrator call over ``h`` [s] with ``u``
    held (an MX Function; differentiable through CVODES/IDAS sensitivities)."""
    _check(model, settings)
    F = integrator(model, settings, HELD, (1.0,))
    x, z = cs.MX.sym("x", model.nx), cs.MX.sym("z", model.nz)
    u, h, p = cs.MX.sym("u", model.u.numel()), cs.MX.sym("h"), cs.MX.sym("p", model.p.numel())
    res = F(x0=x, z0=z, u=u, p=cs.vertcat(p, 0, h))
    return cs.Function(
        "step", [x, z, u, h, p], [res["xf"], res["zf"]], ["x", "z", "u", "h", "p"], ["xf", "zf"]
    )


class UnknownOption(ParameterError):
    """An option name (``option``) CasADi's integrator does not have; ``close``: CasADi's
    nearest names."""

    def __init__(self, name: str, value: object, plugin: str, option: str, close: list) -> None:
        e_g = f", e.g. {', '.join(close)}" if close else ""
        allowed = f"options of casadi.integrator('{plugin}'){e_g}"
        super().__init__(name, value, allowed, f"unknown option '{option}'")
        self.close = close


def _refusal(plugin: str, name: str, value: object, text: str) -> ParameterError:
    """CasADi's refusal ``text`` of integrator options, on one line: an
    :class:`UnknownOption`, or the value refused (``allowed``: CasADi's last line)."""
    if bad := re.search(r"Unknown option: (\S+)", text):
        return UnknownOption(name, value, plugin, bad[1], re.findall(r'^> "(\w+)"', text, re.M))
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    return ParameterError(name, value, lines[-1][:200], f"refused by {plugin}")


def check_option(plugin: str, key: str, value: object) -> None:
    """Refuse an option ``key = value`` that ``casadi.integrator(plugin)`` would reject,
    before any model is built (a throw-away integrator of ``x' = -x`` is made with it).

    Raises
    ------
    UnknownOption
        ``key`` is not an option of ``plugin`` (with CasADi's nearest names).
    ParameterError
        CasADi refuses the value (``allowed``: CasADi's last line).
    """
    x = cs.SX.sym("x")
    try:
        cs.integrator("probe", plugin, {"x": x, "ode": -x}, 0.0, [1.0], {key: value})
    except RuntimeError as exc:
        raise _refusal(plugin, key, value, str(exc)) from None


def _cause(msg: str) -> str:
    for flag, why in (
        ("CV_TOO_MUCH_WORK", "too many steps (max_steps reached): stiff or a step is too small"),
        ("IDA_TOO_MUCH_WORK", "too many steps (max_steps reached)"),
        ("CV_CONV_FAILURE", "Newton iteration failed to converge repeatedly"),
        ("IDA_CONV_FAIL", "Newton iteration failed to converge repeatedly"),
        ("CV_ERR_FAILURE", "error test failed repeatedly (step size became too small)"),
        ("CV_RHSFUNC_FAIL", "right-hand side evaluation failed (NaN or inf)"),
        ("IDA_RES_FAIL", "residual evaluation failed (NaN or inf)"),
        ("IDA_INIT", "initial algebraic state inconsistent (calc_ic failed)"),
    ):
        if flag in msg:
            return f"{why} [{flag}]"
    return msg.strip().splitlines()[-1][:300]


register_method("cvodes", step_function)(_run)
register_method("idas", step_function)(_run)
