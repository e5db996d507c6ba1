"""What a fit is made of: the estimated parameters, how they enter each model, and the
experiments (time series, static points and targets), all in SI.

Parameters enter a flattened model through its own symbolic parameter vector ``p``
(``Model.p``: every parameter already is a CasADi symbol of the model's Functions, none
is baked in). An experiment states which entries of ``p`` an estimated parameter sets
(:attr:`TimeSeries.uses`): ``p_i = factor * theta_k``, so one estimated value can set
one model parameter (``"regulator.tau"``) or the same field of every unit of a chain
(``aps.k_s`` sets ``myofibril.actin0.k_s``, ``myofibril.actin1.k_s``, ...; the factor is 1
there). Every other entry keeps the experiment's value in :attr:`TimeSeries.p`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..modeling.model import Model

Uses = Mapping[str, tuple[str, float]]
"""Model parameter name -> (estimated parameter name, factor): ``p = factor * theta``."""


@dataclass(frozen=True)
class Estimated:
    """One estimated parameter: name, SI unit, start value and bounds (SI), and whether it
    is searched in ``log`` (default for positive bounds) or linear space.

    The search variable is ``phi = log(theta)`` (log) or ``theta / scale`` (linear, with
    ``scale`` the largest of ``|start|``, ``|low|``, ``|high|`` that is finite and > 0).
    """

    name: str
    unit: str
    start: float
    low: float
    high: float
    log: bool = True

    def __post_init__(self) -> None:
        if not self.low < self.high:
            raise ParameterError(f"{self.name} bounds", (self.low, self.high), "low < high")
        if not self.low <= self.start <= self.high:
            raise ParameterError(
                f"{self.name} start", self.start, f"inside its bounds [{self.low}, {self.high}]"
            )
        if self.log and not self.low > 0:
            raise ParameterError(
                f"{self.name} bounds", (self.low, self.high), "low > 0 for a log-scaled parameter"
            )

    @property
    def scale(self) -> float:
        """The linear search variable's unit (1 for log-scaled parameters)."""
        if self.log:
            return 1.0
        sizes = [abs(v) for v in (self.start, self.low, self.high) if math.isfinite(v) and v]
        return max(sizes) if sizes else 1.0

    def to_phi(self, theta: float | np.ndarray) -> float | np.ndarray:
        """The search variable of a value (SI)."""
        return np.log(theta) if self.log else np.asarray(theta) / self.scale

    def to_theta(self, phi):
        """The value (SI) of a search variable; numbers or CasADi symbols."""
        if self.log:
            return np.exp(phi) if isinstance(phi, float | np.ndarray) else _exp(phi)
        return phi * self.scale

    def dtheta_dphi(self, theta: float) -> float:
        """``d theta / d phi`` at ``theta``."""
        return theta if self.log else self.scale


def _exp(phi):
    import casadi as cs

    return cs.exp(phi)


@dataclass(frozen=True)
class Noise:
    """The standard deviation of one measured signal: ``sigma`` (SI; None: estimated by
    maximum likelihood, one value per signal over all experiments) and a ``relative``
    part: ``sd_i = sqrt(sigma^2 + (relative |data_i|)^2)``."""

    sigma: float | None
    relative: float = 0.0

    def __post_init__(self) -> None:
        if self.sigma is not None and not self.sigma > 0:
            raise ParameterError("sigma", self.sigma, "(0, inf), or None to estimate it")
        if not 0 <= self.relative < 1:
            raise ParameterError("relative", self.relative, "[0, 1)")
        if self.sigma is None and self.relative:
            raise ParameterError(
                "relative",
                self.relative,
                "0 when sigma is estimated (a relative part needs a known sigma)",
            )


@dataclass
class TimeSeries:
    """A transient from the equilibrium at the first input values.

    ``t`` (n,) [s] strictly increasing; ``u`` (n, nu): every model input at the samples
    (linear between samples); ``outputs``: measured signals (any of
    ``model.signal_names``); ``data`` (n, ny) in SI (NaN: not measured at that sample);
    ``p``: the model's parameter vector for this experiment, ``uses``: where the estimated
    parameters enter it. ``interval``: samples per shooting interval (multiple shooting;
    ``None``: one interval, single shooting); ``step``: samples one Radau IIA step spans
    at most (steps also end at every kink of the inputs; ``None``: chosen by
    :func:`.shooting.auto_step` at the start values).
    """

    name: str
    model: Model
    t: np.ndarray
    u: np.ndarray
    outputs: Sequence[str]
    data: np.ndarray
    p: np.ndarray
    uses: Uses = field(default_factory=dict)
    interval: int | None = 50
    step: int | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.u = np.asarray(self.u, dtype=float).reshape(len(self.t), -1)
        self.data = np.asarray(self.data, dtype=float).reshape(len(self.t), -1)
        self.p = np.asarray(self.p, dtype=float)
        if self.model.nz:
            raise ParameterError(
                f"experiment '{self.name}'",
                self.model.name,
                f"a model without algebraic unknowns (this one keeps {self.model.nz}): the "
                "time-series fit collocates an explicit ODE",
            )
        if len(self.t) < 2 or not np.all(np.diff(self.t) > 0):
            raise ParameterError(f"experiment '{self.name}' time", "", "strictly increasing")
        if self.u.shape[1] != self.model.u.numel():
            raise ParameterError(
                f"experiment '{self.name}' inputs", self.u.shape[1], f"{self.model.input_names}"
            )
        if self.data.shape[1] != len(self.outputs):
            raise ParameterError(f"experiment '{self.name}' data", self.data.shape, "n x outputs")
        for key, s in (("interval", self.interval), ("step", self.step)):
            if s is not None and (isinstance(s, bool) or not isinstance(s, int) or s < 1):
                raise ParameterError(f"experiment '{self.name}' {key}", s, "an integer >= 1")


@dataclass
class StaticPoint:
    """One equilibrium ``ode = 0, alg = 0`` at inputs ``u`` and parameters ``p`` (with the
    estimated ones entering by ``uses``). ``links``: model parameter -> (point name,
    signal): that parameter set to another point's solved signal (the calibration's
    isometric fixture at the hanging chain's rest position)."""

    name: str
    model: Model
    u: np.ndarray
    p: np.ndarray
    uses: Uses = field(default_factory=dict)
    links: Mapping[str, tuple[str, str]] = field(default_factory=dict)


@dataclass
class Target:
    """A measured static quantity: ``value`` (SI) against ``expr(signal)``, where
    ``signal(point, name)`` returns a point's solved signal symbolically; ``signal`` groups
    targets for the noise (:class:`Noise` by this name)."""

    name: str
    expr: Callable
    value: float
    signal: str


def measured(point: str, signal: str, value: float) -> Target:
    """The target "signal ``signal`` of point ``point`` measured as ``value``"."""
    return Target(f"{point}:{signal}", lambda sig: sig(point, signal), value, signal)


def check_uses(model: Model, uses: Uses, names: Sequence[str], where: str) -> None:
    """Refuse a use of an unknown model parameter or estimated parameter."""
    for pname, (ename, _) in uses.items():
        if pname not in model.param_names:
            raise ParameterError(f"{where} uses", pname, f"a parameter of model '{model.name}'")
        if ename not in names:
            raise ParameterError(f"{where} uses", ename, f"an estimated parameter: {list(names)}")


__all__ = ["Estimated", "Noise", "StaticPoint", "Target", "TimeSeries", "measured"]
