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
* **each signal's mean shift**: second-order averaging on the whole model: the period
  mean of the ODE's and the signal's second-order terms along the harmonic responses
  ``Z_k = [X_k; U_k]``, ``sum_k q(Re Z_k) + q(Im Z_k)`` with ``q(v) = v' H v`` (CasADi's
  second directional derivatives), moves the orbit's mean by ``dx = -A^-1 drive`` and
  the signal by ``C dx`` plus its own term; bounded by the same sums of magnitudes,
  ``|C A^-1| |drive| + |direct|`` (no cancellation; :data:`SAFETY`).

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

import casadi as cs
import numpy as np

from ..equilibrium import solve_equilibrium
from ..errors import ParameterError
from ..modeling.model import Model

HARMONICS = 60
"""Harmonics of the square wave in the ripple sum (its terms fall like 1/k with the
command and like 1/k^2 or faster through the model's first-order lags)."""

SAFETY = 3.5
"""Factor on the predicted error: measured/estimated (the largest deviation of the
switched run from the averaged equilibrium once periodic, 1.3-1.5 s after the start)
was 0.09-2.33 on the hose and chamber pressures and the length over duty 0.2-0.8 x
20/50/100 Hz (n = 3, 20 g, ``benchmarks/pwm_ripple.py``); 3.5 leaves 50 % on 2.33. The
mean shift is a bound (the terms' magnitudes summed): the signed second-order sum crossed
zero near duty 0.41 where the measured shift did not (ratio 6.4 there)."""

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
    # each phase's net valve flow at the hose pressure: value and slope there
    q = {o: [flow(o, 1 + k * h) for k in (-1, 0, 1)] for o in (1.0, 0.0)}
    g = {o: (v[2] - v[0]) / (2 * h * p_hose) for o, v in q.items()}
    T = pwm.period
    a_on, a_off = (p_hose - q[o][1] / g[o] for o in (1.0, 0.0))
    pp, _ = _periodic(d, T, a_on, -C / g[1.0], a_off, -C / g[0.0])
    out = RipplePrediction(d, T, -C / g[1.0], -C / g[0.0], pp, 0.0)
    _signal_errors(model, name, eq, p, d, T, signals, out, params, f"{valve}_hose.p")
    return out


def _second_order(model: Model, names: list[str]) -> cs.Function:
    """``(x, u, p, v) -> (v' H_f v, v' H_y v)``: the second derivative of the ODE and of
    the signals ``names`` along ``v`` in ``[x; u]`` (cached on the model)."""

    def build() -> cs.Function:
        w = cs.vertcat(model.x, model.u)
        v = cs.SX.sym("v", w.numel())
        idx = [model.signal_names.index(n) for n in names]
        y = model.function("signals")(model.x, cs.SX(0, 1), model.u, model.p)[idx]
        second = [cs.jtimes(cs.jtimes(e, w, v), w, v) for e in (model.ode, y)]
        return cs.Function("second", [model.x, model.u, model.p, v], second)

    return model.cached(("ripple_second_order", *names), build)


def _signal_errors(model, name, eq, p, d, T, signals, out, params, p_name) -> None:
    """Fill ``out.mean_shift``, ``out.error`` and ``out.span`` (module docstring)."""
    if model.nz:
        raise ParameterError(
            "fidelity", model.name, "a level without algebraic unknowns for the ripple"
        )
    names = list(dict.fromkeys([*signals, p_name]))
    A, B, Cm, D = (np.array(M) for M in model.linearization(names)(eq.x, eq.z, [d], p))
    second = _second_order(model, names)
    w = 2 * math.pi / T
    eye = np.eye(A.shape[0])
    ripple = np.zeros(len(names))
    drive, direct = np.zeros(A.shape[0]), np.zeros(len(names))
    drive_abs, direct_abs = np.zeros(A.shape[0]), np.zeros(len(names))
    for k in range(1, HARMONICS + 1):
        # the pulse's k-th complex coefficient (on over [0, d T)) and the response to it
        U = (1.0 - np.exp(-2j * math.pi * k * d)) / (2j * math.pi * k)
        X = np.linalg.solve(1j * k * w * eye - A, B[:, 0] * U)
        ripple += 2.0 * np.abs(Cm @ X + D[:, 0] * U)
        # the period mean of the second-order terms: sum_k q(Re Z_k) + q(Im Z_k)
        Z = np.concatenate([X, [U]])
        for part in (Z.real, Z.imag):
            f2, y2 = (np.array(v).ravel() for v in second(eq.x, [d], p, part))
            drive += f2
            direct += y2
            drive_abs += np.abs(f2)
            direct_abs += np.abs(y2)
    # the mean shift of the periodic orbit: A dx + drive = 0, dy = C dx + direct; its
    # bound takes every term's magnitude (no cancellation between the harmonics, the
    # states or the terms: the signed sum crosses zero where the true shift does not)
    G0 = Cm @ np.linalg.inv(A)
    out.mean_shift = float((-G0 @ drive + direct)[names.index(p_name)])
    shift = np.abs(G0) @ drive_abs + direct_abs
    ends = [solve_equilibrium(model, {name: v}, params, guess=eq) for v in (0.0, 1.0)]
    for i, n in enumerate(names[: len(signals)]):
        out.error[n] = SAFETY * (abs(shift[i]) + ripple[i])
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


__all__ = ["RipplePrediction", "ValveChoice", "choose_level", "predict"]
