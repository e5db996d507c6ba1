"""The part both MPCs share: a receding-horizon controller of one tracked output.

:class:`RecedingHorizon` holds what :class:`~.lmpc.LinearMPC` and
:class:`~.nmpc.NonlinearMPC` have in common: the settings checks of a horizon, the sample
time against the regulator lag, the input bounds, the reachable output range (reference
clipping), the held input and the plan, the parameters fed at run time and the
reference preview. Both declare lower bounds on signals the same way
(:func:`soft_bounds`: signal, bound, penalty). The registry factories share
:func:`mpc_settings`, :func:`factory_bounds` and :func:`with_estimator`.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping, Sequence
from fnmatch import fnmatchcase

import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium, solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .disturbance import RANDOM_WALK, check_disturbance
from .ekf import OFFSETS, make_ekf, measured_signals
from .estimated import OnEstimate
from .registry import count, own_settings, positive

TENSIONS = "myofibril.actin*.T"
"""Every thread tension (a pattern of :func:`soft_bounds`; bounded below by the scene's
``tension_min``)."""

COMMON = ("output", "u_min", "u_max")
"""Settings fields the scene sets through the registry's common keys."""

ESTIMATOR_DEFAULTS = {"estimator": "none", "ekf": {}}
"""Own registry keys of both MPCs: run on the states ("none") or on an EKF ("ekf")."""

MAX_HORIZON = 200
"""Longest horizon [samples]. The LMPC's condensed QP is dense: its Hessian has
``(horizon nu)^2`` entries and its prediction matrices ``horizon^2 (nx + 1) nu``, so
memory and solve time grow with the square and the cube of the horizon (``horizon = 10^6``
asked for terabytes); the RTI's condensing grows likewise. 200 samples are 2 s at 10 ms,
40 times the regulator lag; the scenes use 20."""


def check_horizon(name: str, value: object) -> int:
    """A horizon: an integer in ``[1, MAX_HORIZON]``."""
    return count(name, value, 1, MAX_HORIZON, "a dense condensed problem grows as horizon^2")


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


class RecedingHorizon(Controller):
    """A receding-horizon controller of ``settings.output`` by every input of ``model``.

    Parameters
    ----------
    model : Model
        The prediction model.
    dt : float
        Sample time [s]; ``settings.horizon * dt`` must cover the regulator lag.
    settings : frozen dataclass
        With at least ``horizon``, ``u_min``, ``u_max`` [SI] and ``output``.
    outputs : list of str
        The signals the controller reads.
    params : mapping of str to float, optional
        Parameter overrides of ``model`` by name (SI), e.g. the plant's load; the values
        :meth:`reset` restores (:meth:`set_parameters` changes them at run time).

    Attributes
    ----------
    clip : ReferenceClip
        The reachable range of the output over the input bounds.
    """

    def __init__(
        self,
        model: Model,
        dt: float,
        settings,
        outputs: list[str],
        params: Mapping[str, float] | None = None,
    ) -> None:
        s, names = settings, model.input_names
        lo, hi = dict.fromkeys(names, s.u_min), dict.fromkeys(names, s.u_max)
        super().__init__(dt, names, outputs, lo, hi)
        check_dt(self.slug, model, self.dt, s.horizon)
        self.model, self.settings = model, s
        self._u_lo = np.full(len(names), s.u_min)
        self._u_hi = np.full(len(names), s.u_max)
        self.clip = ReferenceClip(model, s.output, names[0], (s.u_min, s.u_max), params)
        nominal = np.asarray(model.parameters(params), dtype=float).ravel()
        self._p_nominal = np.concatenate([nominal, np.zeros(len(self.offsets))])
        self._p = self._p_nominal.copy()

    offsets: tuple[str, ...] = ()
    """Run-time inputs of the prediction that are not model parameters, appended to the
    parameter vector (the NMPC's input and output disturbances, :data:`~.ekf.OFFSETS`;
    0 by default)."""

    @property
    def runtime_parameters(self) -> tuple[str, ...]:
        """Every parameter of the prediction model and the :attr:`offsets`: all are
        run-time inputs of the prediction (see :meth:`set_parameters`)."""
        return (*self.model.param_names, *self.offsets)

    @property
    def parameters(self) -> dict[str, float]:
        """The parameter (and offset) values [SI] the prediction uses now, by name."""
        return dict(zip(self.runtime_parameters, self._p.tolist(), strict=True))

    def set_parameters(self, values: Mapping[str, float]) -> None:
        """Predict with ``values`` [SI, by name] from the next sample on (e.g. an
        estimator's load); the others keep their values. :meth:`reset` restores the
        values given at construction.

        Raises
        ------
        ParameterError
            For a name not of :attr:`runtime_parameters` or a non-finite value.
        """
        names = self.runtime_parameters
        for name, value in values.items():
            where = f"{self.slug}.parameters.{name}"
            if name not in names:
                raise ParameterError(where, value, f"one of {list(names)}")
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ParameterError(where, value, "a finite number [SI]")
            self._p[names.index(name)] = float(value)

    def reset(self, u0: Mapping[str, float] | np.ndarray) -> None:
        """Hold ``u0`` (by name, or a vector in input order; clipped into the bounds) and
        forget the plan; a subclass also forgets its own warm start."""
        super().reset(u0)
        vec = [u0[n] for n in self.inputs] if isinstance(u0, Mapping) else u0
        self._u = np.clip(np.asarray(vec, float).reshape(-1), self._u_lo, self._u_hi)
        self._plan: np.ndarray | None = None
        self._p = self._p_nominal.copy()
        self._preview: np.ndarray | None = None

    @property
    def preview_samples(self) -> int:
        """One reference per node of the horizon."""
        return self.settings.horizon

    def set_preview(self, values: Mapping[str, Sequence[float]]) -> None:
        """The reference of the tracked output at the next ``horizon`` samples [SI], for the
        next :meth:`update` only (each clipped to the reachable range like ``r(t)``).

        Raises
        ------
        ParameterError
            Unless ``values`` holds exactly the tracked output with ``horizon`` values.
        """
        out, n = self.settings.output, self.settings.horizon
        if set(values) != {out} or np.size(values[out]) != n:
            raise ParameterError(
                f"{self.slug}.preview",
                {k: int(np.size(v)) for k, v in values.items()},
                f"{{'{out}': {n} values}} (one per node of the horizon)",
            )
        ahead = np.asarray(values[out], float).ravel()
        self._preview = np.array([self.clip({out: v}) for v in ahead])

    def nodes(self, ref: float) -> np.ndarray:
        """The reference at nodes ``1..horizon`` [SI] for this sample: the preview if one was
        set since the last update (then forgotten), else ``ref`` (``r(t)``, clipped) held."""
        ahead, self._preview = self._preview, None
        return np.full(self.settings.horizon, ref) if ahead is None else ahead


def own_defaults(settings_class) -> dict:
    """The defaults of a settings dataclass, without the fields the common keys set."""
    return {f.name: f.default for f in dataclasses.fields(settings_class) if f.name not in COMMON}


def mpc_settings(
    slug: str,
    model: Model,
    settings: Mapping[str, object],
    settings_class,
    extra: Mapping,
    tension_default: float | None,
) -> tuple[dict, str, Mapping]:
    """A factory's settings: the fields of ``settings_class`` not set by the common keys,
    the ``extra`` keys and :data:`ESTIMATOR_DEFAULTS`; with the input checked, the common
    keys ``output``, ``u_min``, ``u_max`` added, ``soft_min`` from
    :func:`factory_bounds` (``tension_default``) and ``output_std`` from the output's
    noise (``noise_std``) unless given.
    Returns ``(own, estimator, ekf_settings)``, ``own`` without the estimator keys.

    Raises
    ------
    ParameterError
        For an unknown key (:func:`~.registry.own_settings`) or an input not of ``model``.
    """
    own = own_settings(
        slug, settings, {**own_defaults(settings_class), **extra, **ESTIMATOR_DEFAULTS}
    )
    if settings["input"] not in model.input_names:
        raise ParameterError(f"{slug}.input", settings["input"], f"one of {model.input_names}")
    noise = (settings.get("noise_std") or {}).get(settings["output"])
    if own["output_std"] is None and noise:
        own["output_std"] = float(noise)
    own.update(
        output=settings["output"],
        u_min=float(settings["u_min"]),
        u_max=float(settings["u_max"]),
        soft_min=factory_bounds(settings, tension_default),
    )
    return own, own.pop("estimator"), own.pop("ekf")


def ekf_disturbance(
    slug: str,
    model: Model,
    disturbance: object,
    ekf_settings: Mapping[str, object],
) -> Mapping[str, object]:
    """The EKF settings with the ``disturbance`` model (:mod:`.disturbance`) as what it
    estimates: "load" the load mass (2 g/sqrt(s)), "input" and "output" the offsets of
    :data:`~.ekf.OFFSETS` (:data:`~.disturbance.RANDOM_WALK`), "none" nothing; None (the
    default) leaves the EKF's own default (the load where the plant has one). An explicit
    ``ekf.disturbance_std`` wins over the default but not over a model given here.

    Raises
    ------
    ParameterError
        For an unknown model, or "load" on a plant without one.
    """
    if disturbance is None:
        return ekf_settings
    kind = check_disturbance(slug, disturbance, model.param_names)
    if not isinstance(ekf_settings, Mapping):
        return ekf_settings  # make_ekf refuses it
    name = {"load": "load.m", "input": OFFSETS[0], "output": OFFSETS[1]}.get(kind)
    std = {} if name is None else {name: RANDOM_WALK[kind]}
    return {**ekf_settings, "disturbance_std": std}


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
    measured = measured_signals(slug, settings, settings["output"])
    out = settings["output"] if settings["output"] in measured else None
    ekf = make_ekf(model, op, dt, measured, settings.get("noise_std"), ekf_settings, out)
    return OnEstimate(ctl, ekf, model, op)


def check_mpc_settings(slug: str, s) -> None:
    """The checks both MPCs' settings ``s`` share (``slug``: "lmpc" or "nmpc"): the
    horizon, the weights, the rate limit, the soft bounds (stored as a tuple of tuples)
    and their penalty, the filter's noise and the command bounds."""
    check_horizon(f"{slug}.horizon", s.horizon)
    positive(slug, "weight_y", s.weight_y)
    positive(slug, "weight_du", s.weight_du, allow_zero=True)
    positive(slug, "rate_max", s.rate_max)
    positive(slug, "soft_penalty", s.soft_penalty)
    object.__setattr__(s, "soft_min", check_soft_min(slug, s.soft_min))
    positive(slug, "input_std", s.input_std, allow_zero=True)
    if s.output_std is not None:
        positive(slug, "output_std", s.output_std)
    if not s.u_min < s.u_max:
        raise ParameterError(f"{slug}.u_max", s.u_max, f"> u_min = {s.u_min:g} Pa")


def check_soft_min(slug: str, declared: object) -> tuple:
    """Lower bounds on signals as declared (a sequence of ``(signal, bound)`` or
    ``(signal, bound, penalty)``, lists from a scene file too) as a tuple of tuples.

    Raises
    ------
    ParameterError
        Naming ``<slug>.soft_min`` for another shape, a bound that is not a finite number
        or a penalty that is not a number > 0 (``inf``: a hard bound).
    """

    def valid(e) -> bool:
        return (
            isinstance(e, Sequence)
            and not isinstance(e, str)
            and len(e) in (2, 3)
            and isinstance(e[0], str)
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in e[1:])
            and math.isfinite(e[1])
            and (len(e) == 2 or e[2] > 0)
        )

    if isinstance(declared, str) or not isinstance(declared, Sequence):
        declared = [declared]  # refused below
    if not all(valid(e) for e in declared):
        raise ParameterError(
            f"{slug}.soft_min", declared, "[signal, bound] or [signal, bound, penalty] pairs: "
            "bound finite [SI], penalty > 0 (inf: hard)"
        )  # fmt: skip
    return tuple(tuple(e) for e in declared)


def soft_bounds(
    slug: str, model: Model, declared: Sequence, penalty: float
) -> list[tuple[str, float, float]]:
    """The lower bounds ``signal >= bound`` of an MPC, one declaration for both MPCs
    (as do-mpc's ``set_nl_cons``): each entry ``(signal, bound[, penalty])`` of
    :func:`check_soft_min`, the signal a name or a pattern (``*``, e.g.
    :data:`TENSIONS`) of ``model``'s signals, the penalty [per unit of the signal] of the
    violation ``s >= 0`` costing ``penalty (s + s^2)`` (default ``penalty``; ``inf``: a
    hard bound). Returns one ``(name, bound, penalty)`` per signal matched, in order.

    Raises
    ------
    ParameterError
        For a signal or pattern that matches no signal of ``model``.
    """
    out = []
    for entry in check_soft_min(slug, declared):
        signal, bound, weight = (*entry, penalty)[:3]
        names = [n for n in model.signal_names if fnmatchcase(n, signal)]
        if not names:
            raise ParameterError(f"{slug}.soft_min", signal, "a signal (or pattern) of the model")
        out.extend((n, float(bound), float(weight)) for n in names)
    return out


def factory_bounds(settings: Mapping[str, object], tension_default: float | None) -> tuple:
    """The lower bounds a registry factory gives its MPC: the own key ``soft_min``
    (default none) and every thread tension (:data:`TENSIONS`) >= the common key
    ``tension_min`` (``tension_default`` when not given; None: no tension bound)."""
    declared = tuple(settings.get("soft_min") or ())
    tmin = settings.get("tension_min")
    tmin = tension_default if tmin is None else float(tmin)
    return declared if tmin is None else (*declared, (TENSIONS, tmin))
