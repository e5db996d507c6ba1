"""The pulse-width modulator: an input law from a duty cycle to an on/off valve command.

A model whose input drives an on/off valve (:class:`~..components.valve.SwitchingValve`)
carries a :class:`PWM` for that input in :attr:`Model.modulators`; the
:class:`~.simulator.Simulator` applies it to the input's signal (the duty cycle, 0-1)
before it integrates:

* ``switched``: the command is the :class:`PulseTrain` of the duty: 1 while the phase of
  a sawtooth carrier of the PWM period (anchored at t = 0) is below the effective duty,
  else 0, the whole train shifted by the valve's switching ``delay``. Every switching
  instant is a breakpoint: each method integrates the pieces between two edges with the
  command held, and no step crosses an edge (docs/numerics.md).
* ``averaged``: the command is the effective duty itself (no edges): the valve's opening
  then follows the duty, and the flow is the duty-weighted (PWM-averaged) flow
  (docs/model.md).

The effective duty applies the minimum on-time ``min_on``: a pulse (or a gap) shorter
than ``min_on`` is not made (duty 0, or 1). The duty is sampled by the carrier as it
comes (a comparator): it must be piecewise constant (a constant, step, staircase, or a
controller's held value); a ramp or a sine would need the crossing instants found, and
is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError

LEVELS = ("switched", "averaged")
"""Valve model levels: the PWM's pulses, or their average."""


@dataclass(frozen=True)
class PWM:
    """Pulse-width modulation of one input.

    Attributes
    ----------
    frequency : float
        PWM frequency [Hz], (0, 10 kHz]; default 50 Hz (the middle of the 20-100 Hz
        band of solenoid-valve PWM in soft robotics; estimate).
    min_on : float
        Minimum on-time (and off-time) [s], ``[0, period/2)``; default 0.
    delay : float
        Switching delay of the valve [s], ``[0, period)``: the command's edges reach the
        valve this much later (default 0; the valve's own default is passed by the
        supply builder).
    level : str
        One of :data:`LEVELS`.
    """

    frequency: float = 50.0
    min_on: float = 0.0
    delay: float = 0.0
    level: str = "switched"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.frequency) and 0 < self.frequency <= 1e4):
            raise ParameterError("pwm_frequency", self.frequency, "(0, 10000] Hz")
        if not (0 <= self.min_on < 0.5 * self.period):
            raise ParameterError("pwm_min_on", self.min_on, f"[0, {0.5 * self.period:g}) s")
        if not (0 <= self.delay < self.period):
            raise ParameterError("valve_delay", self.delay, f"[0, {self.period:g}) s")
        if self.level not in LEVELS:
            raise ParameterError("valve_level", self.level, f"one of {LEVELS}")

    @property
    def period(self) -> float:
        """The PWM period [s]."""
        return 1.0 / self.frequency

    def effective_duty(self, duty: float | np.ndarray) -> float | np.ndarray:
        """The duty the valve sees [1]: 0 where the pulse would be shorter than
        ``min_on``, 1 where the gap would be."""
        d = np.asarray(duty, dtype=float)
        short = self.min_on * (1.0 - 1e-9) / self.period  # "shorter", rounding aside
        out = np.where(d < short, 0.0, np.where(1.0 - d < short, 1.0, d))
        return float(out) if np.ndim(duty) == 0 else out

    def law(self, duty: object, previous: object, t_switch: float) -> object:
        """The signal the model's equations see, driven by the piecewise-constant
        ``duty`` from ``t_switch`` [s] on (``previous`` before it)."""
        if self.level == "averaged":
            return EffectiveDuty(self, duty)
        return PulseTrain(self, duty, previous, t_switch)


@dataclass(frozen=True)
class EffectiveDuty:
    """The averaged law: the PWM's effective duty of a piecewise-constant ``duty``."""

    pwm: PWM
    duty: object
    unit = "1"

    def __call__(self, t):
        return self.pwm.effective_duty(self.duty(t))

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        return self.duty.breakpoints(t0, tf)

    def casadi(self, t):
        raise _mixed()


@dataclass(frozen=True)
class PulseTrain:
    """The switched law: the valve command (0 or 1) of ``duty`` (``previous`` before
    ``t_switch``), see the module docstring. Its breakpoints are every rising and falling
    edge and the instants where the delayed duty changes."""

    pwm: PWM
    duty: object
    previous: object
    t_switch: float
    unit = "1"

    def _duty(self, s: np.ndarray) -> np.ndarray:
        """Effective duty at carrier times ``s`` (the valve's time minus the delay)."""
        new = np.asarray(self.duty(s), dtype=float) * np.ones_like(s)
        old = np.asarray(self.previous(s), dtype=float) * np.ones_like(s)
        return self.pwm.effective_duty(np.where(s >= self.t_switch, new, old))

    def __call__(self, t):
        s = np.asarray(t, dtype=float) - self.pwm.delay
        T = self.pwm.period
        phase = s - T * np.floor(s / T)
        out = np.where(phase < self._duty(s) * T, 1.0, 0.0)
        return float(out) if np.ndim(t) == 0 else out

    def breakpoints(self, t0: float, tf: float) -> list[float]:
        T, delay = self.pwm.period, self.pwm.delay
        s0, s1 = t0 - delay, tf - delay
        duty_bps = [self.t_switch, *self.duty.breakpoints(s0, s1)]
        duty_bps += self.previous.breakpoints(s0, min(s1, self.t_switch))
        k = np.arange(math.floor(s0 / T), math.ceil(s1 / T) + 1)
        starts = k * T
        offs = starts + self._duty(starts) * T
        # a duty change inside a period may switch the command at once, and moves that
        # period's falling edge: the change and the new falling edge are both edges
        b = np.asarray(duty_bps, dtype=float)
        moved = np.floor(b / T) * T + self._duty(b) * T
        edges = np.concatenate([starts, offs, b, moved]) + delay
        out: list[float] = []
        for e in sorted({float(e) for e in edges if t0 < e < tf}):
            if not out or e - out[-1] > 1e-12 * (1.0 + abs(e)):  # one instant, to rounding
                out.append(e)
        return out

    def casadi(self, t):
        raise _mixed()


def _mixed() -> ParameterError:
    return ParameterError(
        "inputs",
        "a PWM-modulated input beside a continuously varying one",
        "every other input piecewise constant (constant, step, staircase)",
        "the PWM's command is integrated as a held input between its edges",
    )


__all__ = ["LEVELS", "PWM"]
