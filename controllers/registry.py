"""Controller factories by slug, so the closed loop and the ``closed_loop`` scene kind can
build any controller from its name and a settings table.

A factory is ``factory(model, operating_point, dt, settings) -> Controller``:

* ``model``: the *plant* model the loop drives (a factory may build its own prediction
  model from it, e.g. a smooth flow law);
* ``operating_point``: the :class:`~sarcomere.dynamics.Equilibrium` the loop starts from;
* ``dt``: the sample time [s], checked by :func:`make_controller` against the plant
  (:func:`check_sample_time`);
* ``settings``: a plain dict. The loop sets the :data:`COMMON_KEYS`; every other key is the
  controller's own (the scene's ``[control.controllers.<key>]`` table, values in SI), and
  a factory refuses keys it does not know with a ParameterError naming ``<slug>.<key>``
  (:func:`own_settings` does that).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping

import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError, SarcomereError
from sarcomere.dynamics.modeling.model import Model

from .base import Controller, finite
from .linearize import linearize

Factory = Callable[[Model, Equilibrium, float, dict], Controller]

COMMON_KEYS = {
    "output": "the tracked signal (e.g. 'myofibril.length')",
    "input": "the manipulated input (e.g. 'regulator.p_cmd')",
    "u_min": "lower bound of the input [SI]",
    "u_max": "upper bound of the input [SI]",
    "measured": "signals a realistic sensor set gives (list), for estimators",
    "noise_std": "measurement noise standard deviation by signal [SI] (dict), for estimators",
    "tension_min": "the thread tension constraint [N] (for controllers that can state it)",
    "build_model": "build_model(fidelity='full', flow_law='iso6358', saturate=True) -> Model: "
    "the plant's set-up at another level or flow law, for prediction models (scenes only)",
    "overrides": "the scene's parameter overrides by name (dict), for such a model",
}
"""Keys the loop puts in every factory's ``settings``."""

CONTROLLERS: dict[str, Factory] = {}
"""Slug -> factory. ``pid`` and ``lqi`` register when :mod:`sarcomere.controllers` is
imported."""


VECTOR_CONTROLLERS: set[str] = set()
"""Slugs whose factory takes lists of outputs and inputs (``vector=True``)."""


def register_controller(
    slug: str, factory: Factory, *, replace: bool = False, vector: bool = False
) -> None:
    """Make ``factory`` the builder of controller ``slug`` (``vector``: it takes lists of
    outputs and inputs, as many of each).

    Raises
    ------
    ValueError
        ``slug`` already has a different factory and ``replace`` is false.
    """
    if slug in CONTROLLERS and CONTROLLERS[slug] is not factory and not replace:
        raise ValueError(f"controller '{slug}' already registered ({CONTROLLERS[slug]!r})")
    CONTROLLERS[slug] = factory
    (VECTOR_CONTROLLERS.add if vector else VECTOR_CONTROLLERS.discard)(slug)


def make_controller(
    slug: str, model: Model, op: Equilibrium, dt: float, settings: Mapping[str, object]
) -> Controller:
    """Build the controller registered as ``slug``.

    Raises
    ------
    ParameterError
        For an unknown slug, missing common settings or a sample time outside what the
        plant allows (:func:`check_sample_time`).
    """
    if slug not in CONTROLLERS:
        raise ParameterError("controller", slug, f"one of {sorted(CONTROLLERS)}")
    missing = [k for k in ("output", "input", "u_min", "u_max") if k not in settings]
    if missing:
        raise ParameterError(f"{slug}.settings", sorted(settings), f"keys {missing} set")
    if slug not in VECTOR_CONTROLLERS:
        for key in ("output", "input"):
            if not isinstance(settings[key], str):
                raise ParameterError(
                    f"{slug}.{key}", settings[key], "one signal name", "one input and output"
                )
    check_input_bounds(slug, model, op, settings)
    check_sample_time(slug, model, op, dt)
    return CONTROLLERS[slug](model, op, dt, dict(settings))


def check_input_bounds(
    slug: str, model: Model, op: Equilibrium, settings: Mapping[str, object]
) -> None:
    """Refuse an input range the loop cannot use: ``input`` not an input of ``model``;
    ``u_min``, ``u_max`` not finite numbers with ``u_min < u_max``; a range outside the
    input's own ``[low, high]``; or a range that does not hold the operating point's
    input, at a bound included (the loop starts there: ``u_max = 1 Pa`` at a 50 kPa
    operating point would make the first sample drop the command to 1 Pa).

    Raises
    ------
    ParameterError
        Naming ``<slug>.input``, ``<slug>.u_min`` or ``<slug>.u_max``, the value and the
        allowed range.
    """
    name = settings["input"]
    if not isinstance(name, str):  # a vector controller's inputs: the same bounds each
        for one in name:
            check_input_bounds(slug, model, op, {**settings, "input": one})
        return
    if name not in model.input_names:
        raise ParameterError(f"{slug}.input", name, f"one of {model.input_names}")
    var, unit = model.variables[name], model.unit(name)
    u_op = float(op.u[model.input_names.index(name)])
    lo, hi = settings["u_min"], settings["u_max"]
    for key, value in (("u_min", lo), ("u_max", hi)):
        if not finite(value):
            raise ParameterError(f"{slug}.{key}", value, f"a finite number [{unit}]")
    low, high = var.low, var.high
    if not low <= lo <= u_op:
        raise ParameterError(
            f"{slug}.u_min",
            lo,
            f"[{low:g}, {u_op:g}] {unit}",
            f"between the input's lower bound and the operating point's {name} = {u_op:g}",
        )
    if not (u_op <= hi <= high and hi > lo):
        raise ParameterError(
            f"{slug}.u_max",
            hi,
            f"[{u_op:g}, {high:g}] {unit} and > u_min = {lo:g} {unit}",
            f"at or above the operating point's {name} = {u_op:g}, within its upper bound",
        )


MAX_PREVIEW = 200
"""Most samples of reference preview a PID or LQI takes: the MPCs' longest horizon."""

MIN_SAMPLE_S = 1e-3
"""Shortest sample time [s]: about the time one update of the slowest controller here
takes (the EKF, 1-2 ms), and a fiftieth of the regulator's lag."""


def check_sample_time(slug: str, model: Model, op: Equilibrium, dt: float) -> None:
    """Refuse a sample time below :data:`MIN_SAMPLE_S` or above the slowest time constant
    of the plant at ``op`` (the regulator's 50 ms lag here): sampled slower, the loop
    would not see the actuator it commands.

    Raises
    ------
    ParameterError
        Naming ``<slug>.dt``, the value and the range.
    """
    if not finite(dt):
        raise ParameterError(f"{slug}.dt", dt, "a finite sample time [s]")
    poles = np.linalg.eigvals(linearize(model, op, []).A)
    slowest = float(np.min(np.abs(poles.real))) if len(poles) else 0.0
    high = 1.0 / slowest if slowest > 0 else math.inf
    if not MIN_SAMPLE_S <= dt <= high:
        raise ParameterError(
            f"{slug}.dt",
            dt,
            f"[{MIN_SAMPLE_S:g}, {high:.3g}] s",
            "the upper end is the plant's slowest time constant at the operating point",
        )


class UnknownSettingError(ParameterError):
    """A setting a factory does not know: names it, the closest valid key and them all."""

    def __init__(self, name: str, value: object, valid: list[str]) -> None:
        key = name.rsplit(".", 1)[-1]
        close = (
            difflib.get_close_matches(key, valid, n=1)
            or sorted((v for v in valid if key.startswith(v) or v.startswith(key)), key=len)[-1:]
        )
        hint = f"; did you mean '{close[0]}'?" if close else ""
        SarcomereError.__init__(
            self, f"unknown key '{name}'{hint} (valid keys: {', '.join(valid)})"
        )
        self.name, self.value, self.allowed = name, value, f"one of {valid}"


def own_settings(slug: str, settings: Mapping[str, object], defaults: Mapping[str, object]):
    """The controller's own settings: ``defaults`` overridden by ``settings`` (the
    :data:`COMMON_KEYS` left out), each of the type of its default (a number for a number,
    text for text, true/false, a table, a list; a None default is the factory's to check).
    Numbers must be finite.

    Raises
    ------
    ParameterError
        For a key not in ``defaults`` (:class:`UnknownSettingError`: the closest valid
        key and them all), a value of another type or a non-finite number, naming
        ``<slug>.<key>``, the value and the type expected.
    """
    out = dict(defaults)
    for key, value in settings.items():
        if key in COMMON_KEYS:
            continue
        if key not in defaults:
            raise UnknownSettingError(f"{slug}.{key}", value, sorted(defaults))
        expected = _kind(defaults[key])
        if expected is not None and not _is(value, expected):
            raise ParameterError(f"{slug}.{key}", value, KINDS[expected])
        out[key] = value
    return out


KINDS = {
    "number": "a finite number",
    "text": "text",
    "bool": "true or false",
    "table": "a table",
    "list": "a list",
}
"""What a setting of each kind must be (:func:`own_settings`)."""


def _kind(default: object) -> str | None:
    """The kind of :data:`KINDS` a setting with this default takes (None: left to the
    factory)."""
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, int):
        return None  # a count: the factory checks it with its range (:func:`count`)
    if isinstance(default, float):
        return "number"
    if isinstance(default, str):
        return "text"
    if isinstance(default, Mapping):
        return "table"
    if isinstance(default, list | tuple):
        return "list"
    return None


def _is(value: object, kind: str) -> bool:
    """Whether ``value`` is of ``kind`` (:data:`KINDS`)."""
    if kind == "number":
        return finite(value)
    types = {"text": str, "bool": bool, "table": Mapping, "list": list | tuple}
    return isinstance(value, types[kind])


def max_step(slug: str, rate_max: object, dt: float, u_min: float, u_max: float) -> float:
    """The largest change of the command per sample [input unit]: ``rate_max dt`` for a
    rate limit ``rate_max`` [input unit/s] > 0, at most ``u_max - u_min`` (None: no rate
    limit, the whole range in one sample).

    Raises
    ------
    ParameterError
        Naming ``<slug>.rate_max`` for a value not None and not > 0.
    """
    span = u_max - u_min
    if rate_max is None:
        return span
    return min(positive(slug, "rate_max", rate_max) * dt, span)


def refuse_rate_limit(slug: str, controller) -> None:
    """Refuse a rate-limited controller (``controller.du_max`` below its input's range)
    where its held command is not carried (its python-control I/O system)."""
    name = controller.input
    span = controller.u_max[name] - controller.u_min[name]
    if controller.du_max < span:
        raise ParameterError(
            f"{slug}.rate_max",
            controller.du_max / controller.dt,
            "None (no rate limit)",
            "the I/O system does not carry the held command a rate limit needs",
        )


def count(name: str, value: object, low: int, high: int, why: str = "") -> int:
    """``value`` as an integer in ``[low, high]`` (a horizon, a degree, an iteration or
    sample count), else a ParameterError naming ``name``, the value and the range
    (``why``: where the upper end comes from)."""
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or not low <= value <= high
    ):
        raise ParameterError(name, value, f"an integer in [{low}, {high}]", why)
    return int(value)


def positive(slug: str, key: str, value: object, allow_zero: bool = False) -> float:
    """``value`` as a float > 0 (or >= 0), else a ParameterError naming ``<slug>.<key>``."""
    if not finite(value) or not (value >= 0 if allow_zero else value > 0):
        raise ParameterError(f"{slug}.{key}", value, "[0, inf)" if allow_zero else "(0, inf)")
    return float(value)
