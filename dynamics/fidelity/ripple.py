"""The PWM valve's averaged level: its predicted error against the switched model, and
the deterministic ``auto`` rule that picks it.

The averaged model feeds the valve the PWM's effective duty instead of its pulses
(:mod:`~..simulation.pwm`); what it leaves out is the ripple at the PWM frequency and
the mean shift the ripple causes through the nonlinear flow laws. Both are predicted at
the averaged equilibrium of the held duty, without any switched simulation:

* **pressure ripple, closed form**: the hose and the chambers lumped into one volume
  ``V`` (the tubes' filling constants, 0.4 ms for the APS, are short against the
  period), capacitance ``C = V / (R T)``; each phase's net valve flow linearised at the
  mean pressure ``p``: ``q_on + g_on (p' - p)`` open, ``q_off + g_off (p' - p)`` closed,
  so each phase relaxes to ``a = p - q/g`` with the pneumatic time constant
  ``tau = -C/g``. The periodic solution of the two exponentials over ``d T`` and
  ``(1 - d) T`` gives the peak-to-peak ripple and the shift of the period's mean from
  ``p`` (non-zero where ``g_on != g_off``).
* **each signal's ripple**: the averaged model's linearisation ``G(s)`` from the command
  to the signal, summed over the square wave's harmonics,
  ``sum_k |G(j k w)| 2 |sin(k pi d)| / (k pi)`` (a bound of the peak deviation).
* **each signal's mean shift**: the pressure's shift times the signal's static
  sensitivity to the pressure (two equilibria at ``d +- 0.01``).

The predicted error of a signal is :data:`SAFETY` times its mean shift plus its ripple;
``auto`` takes the
averaged level where every named signal's predicted error is within the tolerance of
its static range over the duty 0-1 (docs/numerics.md).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..equilibrium import solve_equilibrium
from ..errors import ParameterError
from ..modeling.model import Model

HARMONICS = 60
"""Harmonics of the square wave in the ripple sum (its terms fall like 1/k with the
command and like 1/k^2 or faster through the model's first-order lags)."""

SAFETY = 3.5
"""Factor on the predicted error: measured/estimated (the largest deviation of the
switched run from the averaged equilibrium once periodic) was 0.8-3.0 on the hose and
chamber pressures and the length over duty 0.3/0.5/0.7 x 20/50/100 Hz (n = 3, 20 g,
``benchmarks/pwm_ripple.py``); the mean shift through the tubes' nonlinear flow, which
the valve-side estimate leaves out, is most of the rest; 3.5 leaves 15 % on 3.0."""

DUTY_STEP = 0.01
"""Duty step [1] of the static sensitivities (central differences of equilibria)."""

_CHAMBER_V = re.compile(r"\.chamber\.V$")


@dataclass
class RipplePrediction:
    """What :func:`predict` found, SI.

    Attributes
    ----------
    duty : float
        Effective duty [1].
    period : float
        PWM period [s].
    tau_on, tau_off : float
        Pneumatic time constants of the lumped volume, valve open and closed [s].
    pressure_ripple : float
        Peak-to-peak ripple of the lumped pressure [Pa] (closed form).
    mean_shift : float
        Shift of the switched model's mean pressure from the averaged one [Pa].
    error : dict
        Signal -> predicted largest ``|switched - averaged|`` once periodic [SI].
    span : dict
        Signal -> its static range over duty 0..1 [SI].
    """

    duty: float
    period: float
    tau_on: float
    tau_off: float
    pressure_ripple: float
    mean_shift: float
    error: dict = field(default_factory=dict)
    span: dict = field(default_factory=dict)

    def relative(self) -> dict[str, float]:
        """Each signal's predicted error over its span."""
        return {
            k: v / self.span[k] if self.span[k] > 0 else math.inf for k, v in self.error.items()
        }


def _valve(model: Model) -> tuple[str, object, str]:
    """The modulated input, its PWM and the valve's name."""
    if len(model.modulators) != 1:
        raise ParameterError(
            "model", model.name, "a model with one PWM valve supply (supply = 'valve_pwm')"
        )
    name, pwm = next(iter(model.modulators.items()))
    return name, pwm, name.rsplit(".", 1)[0]


def _periodic(d: float, T: float, a_on, tau_on, a_off, tau_off) -> tuple[float, float]:
    """Peak-to-peak and mean of the periodic solution: relaxing to ``a_on`` with
    ``tau_on`` for ``d T``, to ``a_off`` with ``tau_off`` for the rest."""
    e_on, e_off = math.exp(-d * T / tau_on), math.exp(-(1.0 - d) * T / tau_off)
    hi = (a_on * (1 - e_on) + e_on * a_off * (1 - e_off)) / (1 - e_on * e_off)
    lo = a_off * (1 - e_off) + e_off * hi
    mean = 0.0
    if d > 0:
        mean += d * a_on + (lo - a_on) * tau_on * (1 - e_on) / T
    if d < 1:
        mean += (1 - d) * a_off + (hi - a_off) * tau_off * (1 - e_off) / T
    return hi - lo, mean


def predict(
    model: Model,
    duty: float,
    signals: Sequence[str],
    params: Mapping[str, object] | None = None,
) -> RipplePrediction:
    """The averaged level's predicted error on ``signals`` at the held ``duty`` [1]
    (module docstring); ``model`` a PWM valve supply's model at either level."""
    name, pwm, valve = _valve(model)
    d = float(pwm.effective_duty(duty))
    eq = solve_equilibrium(model, {name: d}, params)
    p = model.parameters(params)
    par = dict(zip(model.param_names, p.tolist(), strict=True))
    RT = par["ambient.R"] * par["ambient.T"]
    V = eq[f"{valve}_hose.V"] + sum(eq[k] for k in model.signal_names if _CHAMBER_V.search(k))
    C = V / RT
    # each phase's net valve flow at the hose pressure, linearised there
    ix = model.state_names.index(f"{valve}.x")
    im = model.state_names.index(f"{valve}_hose.m_air")
    sig = model.function("signals")
    iq = model.signal_names.index(f"{valve}.m_flow")
    x = eq.x.copy()

    def flow(opening: float, scale: float) -> float:
        xs = x.copy()
        xs[ix], xs[im] = opening, x[im] * scale
        return float(sig(xs, eq.z, np.array([d]), p)[iq])

    p_hose, h = eq[f"{valve}_hose.p"], 1e-3
    # the net valve flow at each opening: value, slope and curvature in the hose pressure
    q = {o: [flow(o, 1 + k * h) for k in (-1, 0, 1)] for o in (0.0, 1.0)}
    g = {o: (v[2] - v[0]) / (2 * h * p_hose) for o, v in q.items()}
    curv = {o: (v[2] - 2 * v[1] + v[0]) / (h * p_hose) ** 2 for o, v in q.items()}
    phases = [p_hose - q[o][1] / g[o] if o else p_hose - q[o][1] / g[o] for o in (1.0, 0.0)]
    T = pwm.period
    pp, _ = _periodic(d, T, phases[0], -C / g[1.0], phases[1], -C / g[0.0])
    out = RipplePrediction(d, T, -C / g[1.0], -C / g[0.0], pp, 0.0)
    flow_terms = (
        d * g[1.0] + (1 - d) * g[0.0],  # q_p at the mean opening
        d * curv[1.0] + (1 - d) * curv[0.0],  # q_pp (the flow is linear in the opening)
        g[1.0] - g[0.0],  # q_xp
    )
    _signal_errors(model, name, eq, p, d, T, signals, out, params, valve, flow_terms)
    return out


def _signal_errors(model, name, eq, p, d, T, signals, out, params, valve, flow_terms) -> None:
    """Fill ``out.mean_shift``, ``out.error`` and ``out.span`` (module docstring)."""
    p_name, x_name = f"{valve}_hose.p", f"{valve}.x"
    names = list(dict.fromkeys([*signals, p_name, x_name]))
    A, B, Cm, D = (np.array(M) for M in model.linearization(names)(eq.x, eq.z, [d], p))
    w = 2 * math.pi / T
    eye = np.eye(A.shape[0])
    ripple, cross = np.zeros(len(names)), np.zeros((2,))
    for k in range(1, HARMONICS + 1):
        # the square wave's k-th complex coefficient (pulse on [0, d T)); its conjugate
        # pair doubles the sums below
        U = (1.0 - np.exp(-2j * math.pi * k * d)) / (2j * math.pi * k)
        Y = (Cm @ np.linalg.solve(1j * k * w * eye - A, B) + D)[:, 0] * U
        ripple += 2.0 * np.abs(Y)
        P, X = Y[names.index(p_name)], Y[names.index(x_name)]
        cross += 2.0 * np.real([P * np.conj(P), X * np.conj(P)])
    # the mean of the nonlinear valve flow over a period vanishes:
    # q_p <dp> + q_pp <dp^2>/2 + q_xp <dx dp> = 0
    q_p, q_pp, q_xp = flow_terms
    out.mean_shift = -(0.5 * q_pp * cross[0] + q_xp * cross[1]) / q_p
    lo, hi = max(d - DUTY_STEP, 0.0), min(d + DUTY_STEP, 1.0)
    e_lo, e_hi = (solve_equilibrium(model, {name: v}, params, guess=eq) for v in (lo, hi))
    ends = [solve_equilibrium(model, {name: v}, params, guess=eq) for v in (0.0, 1.0)]
    dp = e_hi[p_name] - e_lo[p_name]
    for i, n in enumerate(names[: len(signals)]):
        sens = (e_hi[n] - e_lo[n]) / dp if dp else 0.0
        out.error[n] = SAFETY * (abs(sens * out.mean_shift) + ripple[i])
        out.span[n] = abs(ends[1][n] - ends[0][n])


@dataclass
class ValveChoice:
    """What :func:`choose_level` decided, with its reason (``summary.json``)."""

    level: str
    prediction: RipplePrediction
    tolerance: float
    why: str

    def report(self) -> dict:
        pr = self.prediction
        return {
            "chosen": self.level,
            "tolerance": self.tolerance,
            "why": self.why,
            "predicted_error": pr.error,
            "predicted_relative_error": pr.relative(),
            "pressure_ripple_pp": pr.pressure_ripple,
            "mean_shift": pr.mean_shift,
            "tau_on": pr.tau_on,
            "tau_off": pr.tau_off,
            "period": pr.period,
        }


def choose_level(
    model: Model,
    duty: float,
    signals: Sequence[str],
    tolerance: float,
    params: Mapping[str, object] | None = None,
) -> ValveChoice:
    """ "averaged" where every signal's predicted error is within ``tolerance`` of its
    span, else "switched"; deterministic (no clock), the reason said."""
    if not 0 < tolerance < 1:
        raise ParameterError("tolerance", tolerance, "(0, 1)")
    pr = predict(model, duty, signals, params)
    rel = pr.relative()
    worst = max(rel, key=rel.get)
    verdict = "within" if rel[worst] <= tolerance else "outside"
    why = (
        f"predicted error of the averaged valve {rel[worst]:.3g} of the span of {worst} "
        f"({pr.error[worst]:.3g} SI) is {verdict} the tolerance {tolerance:g} (ripple "
        f"{pr.pressure_ripple:.3g} Pa peak to peak, mean shift {pr.mean_shift:.3g} Pa, "
        f"tau {pr.tau_on:.3g}/{pr.tau_off:.3g} s against the period {pr.period:.3g} s)"
    )
    level = "averaged" if verdict == "within" else "switched"
    return ValveChoice(level, pr, tolerance, why)
