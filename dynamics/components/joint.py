"""A revolute joint driven by tendons: the pulley and the tendon (see docs/model.md, "Joint").

The joint turns about a horizontal axis; its angle ``theta`` [rad] is positive in
flexion. Two tendons leave the pulley (radius ``r``) vertically upwards, on opposite
sides, to the hooks of two chains hung from the frame: the flexor's tendon end sits at
``s_f = s_axis - r theta``, the extensor's at ``s_e = s_axis + r theta`` on the chain
axis (s down). A tendon is the actin thread of :mod:`.aps` on its own: inextensible up
to the thread's end stop (:func:`~.aps.thread_stretch`, stiffness ``k_thread``), exactly
slack when it is more than ``5 STOP_LENGTH`` short of straight. Every force derives from
an energy (the tendon's stretch energy, the joint's kinetic energy, the gravity arm's
potential), so the energy balance closes with the pulley's viscous loss.
"""

from __future__ import annotations

import casadi as cs

from ..errors import ParameterError
from ..modeling import laws
from ..modeling.component import Builder, Component
from ..modeling.ports import FLANGE
from .aps import APSParams, thread_stretch
from .environment import ENVIRONMENT

THREAD = APSParams()

JOINT_DEFAULTS = {
    # name: (value, unit, low, description, source)
    "r": (
        10e-3,
        "m",
        1e-6,
        "pulley radius",
        "estimate: a 20 mm pulley maps the chains' few-mm strokes onto about one radian",
    ),
    "J": (
        6.7e-5,
        "kg*m^2",
        1e-12,
        "inertia of the joint about its axis (pulley and link)",
        "estimate: a 20 g link 100 mm long, m l^2 / 3",
    ),
    "d": (
        1e-3,
        "N*m*s/rad",
        0.0,
        "viscous damping of the joint bearing",
        "estimate: a small plain bearing with grease",
    ),
    "m_arm": (0.0, "kg", 0.0, "mass of the gravity arm (0: none)", "set-up choice"),
    "l_arm": (
        0.1,
        "m",
        0.0,
        "distance of the arm's mass from the axis",
        "estimate: the 100 mm link",
    ),
}
"""Defaults of :class:`Pulley`'s parameters: value, SI unit, lower bound, description,
source."""

TENDON_LENGTH = 20e-3
"""Default tendon length [m] (estimate: the hook-to-pulley distance of a bench set-up)."""


class Tendon(Component):
    """An inextensible link that goes slack: the thread law of :mod:`.aps` with its end
    stop. ``flange_a`` the upper end (a chain's hook), ``flange_b`` the lower (the
    pulley's tangent point); span ``x = s_b - s_a``; stretch
    ``delta = thread_stretch(x, l)`` (0 while ``x < l - 5 c``); energy
    ``k delta^2 / 2`` [J], tension its gradient ``T = k delta ddelta/dx`` [N]. ``k``
    defaults to the thread's ``k_thread`` (:class:`~.aps.APSParams`), ``l`` to
    :data:`TENDON_LENGTH`."""

    def __init__(self, name: str, l: float = TENDON_LENGTH, k: float = THREAD.k_thread) -> None:
        super().__init__(name)
        self.l, self.k = l, k

    def build(self, b: Builder) -> None:
        l = b.parameter(
            "l",
            self.l,
            "m",
            "tendon length (straight, unstretched)",
            low=1e-6,
            source="estimate: the hook-to-pulley distance of a bench set-up",
        )
        k = b.parameter(
            "k",
            self.k,
            "N/m",
            "axial stiffness on the end stop",
            low=1e-9,
            source="the actin thread's k_thread (APSParams)",
        )
        fa, fb = b.port("flange_a", FLANGE), b.port("flange_b", FLANGE)
        tension, energy = laws.apply(_tendon, [fb.s - fa.s, l, k])
        b.equation(fb.f, tension)
        b.equation(fa.f, -tension)
        b.output("T", tension, "N", "tendon tension (0: slack)", low=0.0)
        b.output("slack", l - (fb.s - fa.s), "m", "how far the tendon is short of straight")
        b.energy("elastic", energy)


def _tendon(span, l, k) -> list:
    """Tension [N] (the energy's gradient in the span) and stretch energy [J] of a tendon
    of length ``l`` [m] and stiffness ``k`` [N/m] over ``span`` [m]."""
    delta = thread_stretch(span, l, 0.0)
    energy = 0.5 * k * delta**2
    return [cs.gradient(energy, span), energy]


class Pulley(Component):
    """The revolute joint: angle ``theta`` [rad] (state, positive in flexion), rate
    ``omega`` [rad/s]; ``J dw/dt = r (T_f - T_e) - d w - m_arm g l_arm sin(theta) +
    tau_load``. Ports ``flange_f`` and ``flange_e``: the tendons' tangent points at
    ``s_axis -/+ r theta`` [m]. Parameters (:data:`JOINT_DEFAULTS`; ``g`` from the
    environment) and ``tau_load`` [N m], a load torque in flexion (a parameter: the
    stiffness is measured by stepping it). Output ``tau`` [N m], the tendons' torque."""

    def __init__(self, name: str, s_axis: float, theta_start: float = 0.0, **values):
        super().__init__(name)
        unknown = set(values) - set(JOINT_DEFAULTS)
        if unknown:
            raise ParameterError("joint", sorted(unknown), f"names of {list(JOINT_DEFAULTS)}")
        self.values = {k: values.get(k, v[0]) for k, v in JOINT_DEFAULTS.items()}
        self.s_axis, self.theta_start = s_axis, theta_start

    def build(self, b: Builder) -> None:
        par = {
            k: b.parameter(k, self.values[k], unit, text, low=low, source=src)
            for k, (_, unit, low, text, src) in JOINT_DEFAULTS.items()
        }
        s_axis = b.parameter(
            "s_axis",
            self.s_axis,
            "m",
            "depth below the frame of the tendons' tangent points at theta = 0",
            source="assembly: each tendon just straight at 0 Pa",
        )
        tau_load = b.parameter(
            "tau_load", 0.0, "N*m", "load torque on the joint in flexion", source="scene"
        )
        g = b.outer(ENVIRONMENT)["g"]
        theta = b.state("theta", self.theta_start, "rad", "joint angle (flexion positive)")
        omega = b.state("omega", 0.0, "rad/s", "joint angular velocity", nominal=1.0)
        ff, fe = b.port("flange_f", FLANGE), b.port("flange_e", FLANGE)
        r = par["r"]
        b.equation(ff.s, s_axis - r * theta)
        b.equation(fe.s, s_axis + r * theta)
        # virtual work: f_f ds_f + f_e ds_e = r (f_e - f_f) dtheta; a tendon pulls up (f < 0)
        tau = r * (fe.f - ff.f)
        arm = par["m_arm"] * g * par["l_arm"]
        b.der(theta, omega)
        b.der(omega, (tau - par["d"] * omega - arm * cs.sin(theta) + tau_load) / par["J"])
        b.output("tau", tau, "N*m", "torque of the tendons on the joint (flexion positive)")
        b.energy("kinetic", 0.5 * par["J"] * omega**2)
        b.energy("gravity", arm * (1.0 - cs.cos(theta)))
        b.energy("load", -tau_load * theta)  # the constant load torque's potential
        b.dissipation("damping", par["d"] * omega**2)


__all__ = ["JOINT_DEFAULTS", "Pulley", "TENDON_LENGTH", "Tendon"]
