"""The one interface every controller implements, so each runs in the same sampled loop.

A controller samples the plant every ``dt`` seconds: it reads the measured outputs ``y``
(by name, SI) and the reference ``r`` (by name, SI), and returns the plant inputs ``u`` (by
input name, SI) that are then held constant until the next sample (zero-order hold). The
loop that drives a :class:`~sarcomere.dynamics.Simulator` with it lives in
:mod:`sarcomere.controllers.loop`; nothing here knows the plant.

Every controller keeps :class:`ControllerStats`: the wall time of each ``update`` (for the
solve-time metrics) and the count of fallbacks (an infeasible or failed optimisation
replaced by a safe input). A controller never returns NaN or an input outside the bounds
it was given: :meth:`Controller.checked` enforces that for every subclass.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from sarcomere.dynamics.errors import ParameterError, SolverError


@dataclass
class ControllerStats:
    """What a run of a controller cost and where it fell back.

    Attributes
    ----------
    solve_times_s : list of float
        Wall time of every ``update`` call [s], Python included.
    fallbacks : int
        Samples where the controller's own method failed and a safe input was used.
    """

    solve_times_s: list[float] = field(default_factory=list)
    fallbacks: int = 0

    @property
    def fallback_fraction(self) -> float:
        """Fallbacks per sample so far [-] (0 before the first sample): 1.0 is a
        controller whose own method never succeeded (an NMPC whose hard bound can never
        hold) and that ran on its safe input only."""
        n = len(self.solve_times_s)
        return self.fallbacks / n if n else 0.0


class Controller(ABC):
    """A sampled controller: ``update(t, y, r) -> u`` every ``dt`` seconds.

    Parameters
    ----------
    dt : float
        Sample time [s], > 0.
    inputs : sequence of str
        Plant inputs it sets (model input names, e.g. ``"regulator.p_cmd"``).
    outputs : sequence of str
        Measured signals it reads (model signal names, e.g. ``"myofibril.length"``).
    u_min, u_max : mapping of str to float
        Bounds of each input [SI]; every returned input lies inside them.
    """

    slug: str = "controller"
    """Short name used as the prefix of its metrics (``pid``, ``lqi``, ``lmpc``, ``nmpc``)."""

    def __init__(
        self,
        dt: float,
        inputs: Sequence[str],
        outputs: Sequence[str],
        u_min: Mapping[str, float],
        u_max: Mapping[str, float],
    ) -> None:
        if not (finite(dt) and dt > 0):
            raise ParameterError(f"{self.slug}.dt", dt, "(0, inf) s")
        self.dt = float(dt)
        self.inputs, self.outputs = list(inputs), list(outputs)
        for name in self.inputs:
            lo, hi = u_min.get(name), u_max.get(name)
            if not (finite(lo) and finite(hi) and lo < hi):
                raise ParameterError(
                    f"{self.slug}.u_bounds.{name}", (lo, hi), "finite low < high [SI]"
                )
        self.u_min = {n: float(u_min[n]) for n in self.inputs}
        self.u_max = {n: float(u_max[n]) for n in self.inputs}
        self.stats = ControllerStats()

    def reset(self, u0: Mapping[str, float]) -> None:
        """Forget the past (integrators, warm starts, stats); ``u0`` is the input held
        before the first sample [SI]."""
        self.stats = ControllerStats()

    @property
    def runtime_parameters(self) -> tuple[str, ...]:
        """Names of the model parameters :meth:`set_parameters` accepts (none here; a
        model-based controller such as the NMPC lists its prediction's)."""
        return ()

    def set_parameters(self, values: Mapping[str, float]) -> None:
        """Use ``values`` [SI, by name] for parameters of the controller's model from the
        next sample on (an estimator feeds its estimates here).

        Raises
        ------
        ParameterError
            Here for any name: this controller has no run-time parameters.
        """
        if values:
            raise ParameterError(
                f"{self.slug}.parameters", sorted(values), "none: no run-time parameters"
            )

    preview: int = 0
    """Samples of the reference ahead a controller without its own preview handling takes
    (a PID's or LQI's ``preview`` setting; 0: ``r(t)`` only)."""

    ahead: tuple[float, ...] = ()
    """The reference ahead handed over by the last :meth:`set_preview` [SI]."""

    @property
    def preview_samples(self) -> int:
        """How many samples of the reference ahead :meth:`set_preview` takes (:attr:`preview`
        here; the MPCs take one per node of their horizon)."""
        return self.preview

    def set_preview(self, values: Mapping[str, Sequence[float]]) -> None:
        """The reference ahead for the next :meth:`update` only: by tracked signal, its
        values [SI] at ``t + dt, ..., t + preview_samples dt`` (the loop calls it before
        every update when the reference is known ahead); kept in :attr:`ahead`.

        Raises
        ------
        ParameterError
            For a controller that takes no preview, or values of more than one signal.
        """
        if values and (not self.preview or len(values) != 1):
            raise ParameterError(f"{self.slug}.preview", sorted(values), "none: no preview")
        self.ahead = tuple(float(v) for v in next(iter(values.values()), ()))[: self.preview]

    @abstractmethod
    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        """The inputs [SI] to hold from ``t`` to ``t + dt``, given the measurement ``y``
        and the reference ``r`` at ``t`` (both by name, SI)."""

    def checked(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        """:meth:`update`, timed, with its arguments and result checked: every signal it
        reads (:attr:`outputs`) present and finite in ``y``, every reference finite, and
        the returned inputs finite and inside the bounds.

        Raises
        ------
        ParameterError
            For a missing or non-finite measurement or a non-finite reference (a NaN from a
            sensor or an estimator would otherwise become a silent command).
        SolverError
            If the controller returned a missing, non-finite or out-of-bounds input.
        """
        for name in self.outputs:
            if not finite(y.get(name)):
                raise ParameterError(
                    f"{self.slug}.y.{name}", y.get(name), f"a finite measurement at t = {t:g} s"
                )
        for name, value in r.items():
            if not finite(value):
                raise ParameterError(
                    f"{self.slug}.r.{name}", value, f"a finite reference at t = {t:g} s"
                )
        tic = time.perf_counter()
        u = self.update(t, y, r)
        self.stats.solve_times_s.append(time.perf_counter() - tic)
        for name in self.inputs:
            v = u.get(name, math.nan)
            if not (math.isfinite(v) and self.u_min[name] <= v <= self.u_max[name]):
                raise SolverError(
                    f"controller '{self.slug}' returned {name} = {v!r} at t = {t:g} s, outside "
                    f"[{self.u_min[name]:g}, {self.u_max[name]:g}] (a bug in the controller)"
                )
        return u


def finite(value: object) -> bool:
    """Whether ``value`` is a real, finite number (numpy scalars included, bools not)."""
    try:
        return not isinstance(value, bool) and math.isfinite(value)
    except TypeError:
        return False
