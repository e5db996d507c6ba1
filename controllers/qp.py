"""Small pieces both MPCs share: setting checks, the exact zero-order-hold discretisation,
the reachable output range (reference clipping) and the QP solvers through ``casadi.conic``.
"""

from __future__ import annotations

import dataclasses
import math
import re
import warnings
from collections.abc import Mapping

import casadi as cs
import numpy as np
import scipy.linalg

from sarcomere.dynamics.equilibrium import Equilibrium, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .ekf import make_ekf
from .estimated import OnEstimate

TENSION = re.compile(r"myofibril\.actin\w*\.T")
"""Thread tension signals (bounded below by ``tension_min``)."""

COMMON = ("output", "u_min", "u_max", "tension_min")
"""Settings fields the scene sets through the registry's common keys."""

ESTIMATOR_DEFAULTS = {"estimator": "none", "ekf": {}}
"""Own registry keys of both MPCs: run on the states ("none") or on an EKF ("ekf")."""

QP_SOLVERS = {
    "qpoases": {"printLevel": "none", "error_on_fail": False},
    "daqp": {"error_on_fail": False},
    # HPIPM's default inf (1e8) is inside the range of our scaled bounds: it then treats
    # them as finite and stops at max_iter (issue 9); 1e6 is far outside every bound here.
    "hpipm": {"error_on_fail": False, "hpipm": {"iter_max": 100, "warm_start": 1}, "inf": 1e6},
}
"""``casadi.conic`` plugins the MPCs accept, with the options they are built with."""


def check_positive(name: str, value: object, allow_zero: bool = False) -> float:
    """``value`` as a float that is finite and > 0 (or >= 0); a ParameterError naming
    ``name`` otherwise."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or not (value >= 0 if allow_zero else value > 0):
        raise ParameterError(name, value, "[0, inf)" if allow_zero else "(0, inf)")
    return float(value)


def check_horizon(name: str, value: object) -> int:
    """A horizon: an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ParameterError(name, value, "an integer >= 1")
    return value


def check_dt(slug: str, model: Model, dt: float, horizon: int) -> None:
    """Refuse a sample time whose horizon cannot see the input act: ``horizon * dt`` must
    cover the regulator lag (``regulator.tau``) at least once."""
    if "regulator.tau" not in model.param_names:
        return
    tau = float(model.parameters()[model.param_names.index("regulator.tau")])
    if horizon * dt < tau:
        raise ParameterError(
            f"{slug}.dt",
            dt,
            f"[{tau / horizon:g}, inf) s with horizon {horizon}",
            f"horizon * dt = {horizon * dt:g} s is shorter than the regulator lag {tau:g} s",
        )


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: ``expm([[A, B], [0, 0]] dt)``."""
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx], M[:nx, nx:] = A, B
    E = scipy.linalg.expm(M * dt)
    return E[:nx, :nx], E[:nx, nx:]


def qp_solver(name: str, H: cs.Sparsity, A: cs.Sparsity) -> cs.Function:
    """A ``casadi.conic`` QP solver built once for the sparsities ``H`` and ``A``."""
    if name not in QP_SOLVERS:
        raise ParameterError("qp_solver", name, f"one of {sorted(QP_SOLVERS)}")
    return cs.conic("qp", name, {"h": H, "a": A}, dict(QP_SOLVERS[name]))


class ReferenceClip:
    """The steady-state range of an output over the input's range; a reference outside it
    is clipped with one warning per run.

    Parameters
    ----------
    model : Model
        The prediction model.
    output : str
        The tracked signal, e.g. ``"myofibril.length"``.
    u_name : str
        The input that moves it.
    u_range : (float, float)
        The input's allowed range [SI].
    params : mapping of str to float, optional
        Parameter overrides of ``model`` (SI).

    Attributes
    ----------
    ends : list of Equilibrium
        The equilibria at the two ends of the input range.
    """

    def __init__(
        self,
        model: Model,
        output: str,
        u_name: str,
        u_range: tuple[float, float],
        params: Mapping[str, float] | None = None,
    ) -> None:
        self.ends = [solve_equilibrium(model, {u_name: u}, params) for u in u_range]
        values = [e[output] for e in self.ends]
        self.low, self.high = min(values), max(values)
        self.output = output
        self.warned = False

    def __call__(self, r: Mapping[str, float]) -> float:
        if self.output not in r:
            raise ParameterError("reference", sorted(r), f"a value for '{self.output}'")
        value = float(r[self.output])
        if not math.isfinite(value):
            raise ParameterError(f"reference.{self.output}", value, "a finite number")
        clipped = min(max(value, self.low), self.high)
        if clipped != value and not self.warned:
            warnings.warn(
                f"reference {self.output} = {value:.6g} is unreachable at steady state "
                f"within the input bounds; clipped to [{self.low:.6g}, {self.high:.6g}]",
                stacklevel=4,
            )
            self.warned = True
        return clipped


def own_defaults(settings_class) -> dict:
    """The defaults of a settings dataclass, without the fields the common keys set."""
    return {f.name: f.default for f in dataclasses.fields(settings_class) if f.name not in COMMON}


def with_estimator(
    slug: str,
    ctl: Controller,
    model: Model,
    op: Equilibrium,
    dt: float,
    settings: Mapping[str, object],
    estimator: str,
    ekf_settings: Mapping[str, object],
) -> Controller:
    """``ctl`` itself ("none") or run on an EKF of the plant ``model`` ("ekf") fed the
    loop's ``measured`` signals (default: the tracked output and ``regulator.p_out``)."""
    if estimator == "none":
        return ctl
    if estimator != "ekf":
        raise ParameterError(f"{slug}.estimator", estimator, "'none' or 'ekf'")
    measured = settings.get("measured") or [settings["output"], "regulator.p_out"]
    ekf = make_ekf(model, op, dt, measured, settings.get("noise_std"), ekf_settings)
    return OnEstimate(ctl, ekf, model, op)
