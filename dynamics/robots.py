"""Set-ups of muscles in a robot: the antagonistic joint and the bundle of parallel fibres.

Built from the same components as :mod:`.assemblies` (each chain at any dynamic level of
:data:`~.schema.FIDELITIES`, fed by its own regulator). Stable signal names:

* joint: ``flexor_regulator.p_cmd`` and ``extensor_regulator.p_cmd`` (inputs, Pa gauge);
  ``joint.theta`` (rad, flexion positive), ``joint.omega`` (rad/s), ``joint.tau`` (N m,
  the tendons' torque), ``stiffness.K`` (N m/rad, the joint's static stiffness at fixed
  commands, :func:`stiffness_expression`), ``flexor_tendon.T``, ``extensor_tendon.T``
  (N); the chains ``flexor.*``, ``extensor.*`` as ``myofibril.*`` of a single chain;
  parameters ``joint.r``, ``joint.J``, ``joint.d``, ``joint.m_arm``, ``joint.l_arm``,
  ``joint.tau_load`` (:data:`~.components.joint.JOINT_DEFAULTS`);
* with ``supply = "valve_pwm"``: ``<side>_valve.cmd`` and ``valve<i>.cmd`` (the duty
  cycles, [1]) in place of the regulators' commands (:mod:`.supply`);
* bundle: ``regulator<i>.p_cmd`` (inputs, i = 1..k), the fibres ``fibre<i>.*``; hanging:
  ``load.s`` (m), ``load.m`` (kg); isometric: ``sensor.f`` (N), ``fixture.s0`` (m).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping

import casadi as cs

from .assemblies import (
    G_DEFAULT,
    GROUPS,
    HOOK_MASS_KG,
    chain,
    end_mass,
    hanging_rest_position,
    records_setup,
)
from .components.aps import APSParams
from .components.environment import Environment
from .components.joint import TENDON_LENGTH, Pulley, Tendon
from .components.mechanical import Fixed, ForceSensor, Mass, Node
from .equilibrium import solve_equilibrium
from .errors import ParameterError
from .modeling.component import Builder, Component, System
from .modeling.model import Model
from .params.core import Quantity
from .plausibility import PlausibilityWarning, implausible_aps, implausible_load
from .schema import WITHOUT_MODEL
from .supply import SUPPLIES, add_supply
from .units import to_si

MAX_FIBRES = 12
"""Most fibres of a bundle (each a chain with its own regulator; cost grows with k)."""


def _arg(value, unit: str, name: str, low: float, low_open: bool = False) -> float:
    """A set-up argument in SI (numbers, or quantity strings), in ``[low, inf)``."""
    q = Quantity(unit=unit, low=low, low_open=low_open)
    v = to_si(value, unit, name)
    if not (math.isfinite(v) and q.contains(v)):
        raise q.refuse(name, value)
    return v


def _check_level(fidelity: str, what: str) -> None:
    if fidelity in WITHOUT_MODEL:
        raise ParameterError(
            "fidelity",
            fidelity,
            "a dynamic level (full, quasi_static, ...)",
            f"'{fidelity}' linearises one chain over its one command's range; {what} has "
            "a command per chain",
        )


def _chains_checked(params, n_values: dict) -> APSParams:
    if params is not None and not isinstance(params, APSParams):
        raise ParameterError("params", params, "an APSParams or None (the paper's APS)")
    p = params or APSParams.from_paper()
    for name, why in implausible_aps(p).items():
        warnings.warn(f"params.{name} = {why}", PlausibilityWarning, stacklevel=4)
    for key, n in n_values.items():
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ParameterError(key, n, "an integer >= 1")
    return p


def supply_name(chain_name: str, supply: str) -> str:
    """The supply component of a chain: ``flexor`` -> ``flexor_regulator`` or
    ``flexor_valve``; ``fibre<i>`` -> ``regulator<i>`` or ``valve<i>``."""
    kind = "regulator" if supply == "regulator" else "valve"
    if chain_name.startswith("fibre"):
        return kind + chain_name.removeprefix("fibre")
    return f"{chain_name}_{kind}"


def _fed_chain(sys, frame, name, n, p, fidelity, flow_law, groups, feed: dict):
    """A chain ``name`` of ``n`` units hung from ``frame``, fed by its own supply
    (:func:`~.supply.add_supply` with ``feed``); returns it and the supply's PWM."""
    myo = chain(n, p, fidelity, flow_law, groups, name=name)
    mf = sys.add(myo)
    sup = add_supply(sys, supply_name(name, feed["supply"]), **feed)
    sys.connect(frame.flange, mf.flange_a)
    sys.connect(sup.port, mf.port)
    return myo, mf, sup.modulators


def _feed(supply, regulator_tau, saturate, regulator_p_max, valve) -> dict:
    """The arguments of :func:`~.supply.add_supply` for every chain, checked."""
    if supply not in SUPPLIES:
        raise ParameterError("supply", supply, f"one of {SUPPLIES}")
    p_max = regulator_p_max
    if p_max is not None:
        p_max = _arg(p_max, "Pa", "regulator_p_max", 0.0, True)
    return {
        "supply": supply,
        "regulator_tau": _arg(regulator_tau, "s", "regulator_tau", 0.0, True),
        "saturate": saturate,
        "p_max": p_max,
        "valve": valve,
    }


def _flat(sys: System, modulators: dict) -> Model:
    """``sys`` flattened, carrying its supplies' PWM (:attr:`Model.modulators`)."""
    model = sys.flatten()
    model.modulators.update(modulators)
    return model


class StiffnessOutput(Component):
    """The output ``K`` [N m/rad]: an expression of the model's own variables."""

    def __init__(self, name: str, expr: cs.SX) -> None:
        super().__init__(name)
        self.expr = expr

    def build(self, b: Builder) -> None:
        b.output(
            "K",
            self.expr,
            "N*m/rad",
            "static joint stiffness -dtau_load/dtheta at the present state and commands "
            "(the linearisation's steady-state gain; exact at an equilibrium)",
        )


def stiffness_expression(model: Model, angle: str, torque: str) -> cs.SX:
    """``K = -1 / (dtheta/dtau)`` with ``dtheta/dtau`` the steady-state shift of the
    state ``angle`` per unit of the parameter ``torque`` under the exact linearisation
    at the present state and inputs: ``A dx + f_tau dtau = 0`` (``z`` eliminated by the
    implicit function theorem), an expression of ``(x, z, u, p)``."""
    i_tau = model.param_names.index(torque)
    tau = model.p[i_tau]
    A = cs.jacobian(model.ode, model.x)
    b = cs.jacobian(model.ode, tau)
    if model.nz:
        g_z = cs.jacobian(model.alg, model.z)
        f_z = cs.jacobian(model.ode, model.z)
        A = A - cs.mtimes(f_z, cs.solve(g_z, cs.jacobian(model.alg, model.x)))
        b = b - cs.mtimes(f_z, cs.solve(g_z, cs.jacobian(model.alg, tau)))
    shift = cs.solve(A, -b)[model.state_names.index(angle)]
    return 1.0 / shift


@records_setup
def antagonistic_joint(
    n_flexor: int = 3,
    n_extensor: int | None = None,
    params: APSParams | None = None,
    fidelity: str = "full",
    tendon_length: float | str = TENDON_LENGTH,
    regulator_tau: float | str = 0.05,
    g: float | str = G_DEFAULT,
    saturate: bool = True,
    flow_law: str = "iso6358",
    groups: int = GROUPS,
    regulator_p_max: float | str | None = None,
    supply: str = "regulator",
    valve: Mapping[str, object] | None = None,
    **joint: float,
) -> Model:
    """A revolute joint (:class:`~.components.joint.Pulley`) driven by an antagonistic
    pair: the flexor chain of ``n_flexor`` units and the extensor of ``n_extensor``
    (default: as many), each hung from the frame, fed by its own regulator and pulling
    the pulley by a :class:`~.components.joint.Tendon`.

    The pulley's tangent points sit ``tendon_length`` [m] below the longer chain's hook
    at rest at 0 Pa (its :func:`~.assemblies.hanging_rest_position`); the other tendon
    is as long as reaches it, so both are just straight at 0 Pa and ``theta = 0``.
    ``joint``: :data:`~.components.joint.JOINT_DEFAULTS` values (``r``, ``J``, ``d``,
    ``m_arm``, ``l_arm``; SI). Other arguments as :func:`~.assemblies.hanging_load`;
    ``supply`` (:data:`~.supply.SUPPLIES`) and ``valve`` (its options) as
    :func:`~.supply.add_supply`, for each muscle (inputs ``flexor_valve.cmd``,
    ``extensor_valve.cmd``: the duty cycles). Levels without a model of their own are
    refused.
    """
    _check_level(fidelity, "a joint")
    n_ext = n_flexor if n_extensor is None else n_extensor
    p = _chains_checked(params, {"n_flexor": n_flexor, "n_extensor": n_ext})
    l_t = _arg(tendon_length, "m", "tendon_length", 0.0, True)
    g = _arg(g, "m/s^2", "g", 0.0, True)
    feed = _feed(supply, regulator_tau, saturate, regulator_p_max, valve)
    chain(max(n_flexor, n_ext), p, fidelity, flow_law, groups)  # the level's limits first
    rest = {n: hanging_rest_position(n, p, fidelity, g, groups) for n in {n_flexor, n_ext}}
    s_axis = max(rest.values()) + l_t
    sys = System(f"joint_f{n_flexor}_e{n_ext}_{fidelity}")
    sys.add(Environment(g=g))
    frame = sys.add(Fixed("frame"))
    pulley = sys.add(Pulley("joint", s_axis=s_axis, **joint))
    modulators = {}
    for side, n in (("flexor", n_flexor), ("extensor", n_ext)):
        myo, mf, pwm = _fed_chain(sys, frame, side, n, p, fidelity, flow_law, groups, feed)
        modulators.update(pwm)
        hook = sys.add(Mass(f"{side}_hook", m=HOOK_MASS_KG + end_mass(myo), s_start=rest[n]))
        tendon = sys.add(Tendon(f"{side}_tendon", l=s_axis - rest[n]))
        sys.connect(mf.flange_b, hook.flange_a)
        sys.connect(hook.flange_b, tendon.flange_a)
        sys.connect(tendon.flange_b, getattr(pulley, f"flange_{side[0]}"))
    bare = sys.flatten()  # the stiffness is an expression of its variables
    sys.add(
        StiffnessOutput("stiffness", stiffness_expression(bare, "joint.theta", "joint.tau_load"))
    )
    return _flat(sys, modulators)


def _bundle_system(k, n, p, fidelity, g, flow_law, groups, feed, name):
    sys = System(name)
    sys.add(Environment(g=g))
    frame = sys.add(Fixed("frame"))
    fibres = [
        _fed_chain(sys, frame, f"fibre{i}", n, p, fidelity, flow_law, groups, feed)
        for i in range(1, k + 1)
    ]
    modulators = {k: v for *_, pwm in fibres for k, v in pwm.items()}
    return sys, [(myo, mf) for myo, mf, _ in fibres], modulators


@records_setup
def bundle(
    k_fibres: int = 3,
    n: int = 3,
    params: APSParams | None = None,
    fidelity: str = "full",
    setup: str = "hanging",
    load_kg: float | str = 0.0,
    length: float | str | None = None,
    regulator_tau: float | str = 0.05,
    g: float | str = G_DEFAULT,
    saturate: bool = True,
    flow_law: str = "iso6358",
    groups: int = GROUPS,
    regulator_p_max: float | str | None = None,
    supply: str = "regulator",
    valve: Mapping[str, object] | None = None,
) -> Model:
    """``k_fibres`` chains of ``n`` units in parallel, hung side by side from the frame,
    each fed by its own supply (``regulator<i>.p_cmd``, or ``valve<i>.cmd`` with
    ``supply = "valve_pwm"``: a fibre is recruited by its command and released by venting
    it), their hooks joined to one load.

    ``setup`` "hanging": a mass of the 1 g hook plus ``load_kg`` [kg] hangs from the
    joined hooks; "isometric": the joined hooks are held by a force sensor on a rigid
    fixture at ``length`` [m] (default: where the bundle hangs at rest at 0 Pa with the
    hook, so the sensor reads 0 there). Other arguments as
    :func:`antagonistic_joint`.
    """
    _check_level(fidelity, "a bundle")
    if setup not in ("hanging", "isometric"):
        raise ParameterError("setup", setup, "'hanging' or 'isometric'")
    if isinstance(k_fibres, bool) or not isinstance(k_fibres, int):
        raise ParameterError("k_fibres", k_fibres, f"an integer in [1, {MAX_FIBRES}]")
    if not 1 <= k_fibres <= MAX_FIBRES:
        raise ParameterError("k_fibres", k_fibres, f"[1, {MAX_FIBRES}]")
    p = _chains_checked(params, {"n": n})
    load = _arg(load_kg, "kg", "load_kg", 0.0)
    if setup == "isometric" and load > 0:
        raise ParameterError("load_kg", load_kg, "0 on the isometric fixture", "no load hangs")
    if why := implausible_load(load / k_fibres):
        warnings.warn(f"load_kg = {why}", PlausibilityWarning, stacklevel=3)
    g = _arg(g, "m/s^2", "g", 0.0, True)
    feed = _feed(supply, regulator_tau, saturate, regulator_p_max, valve)
    name = f"bundle_k{k_fibres}_n{n}_{fidelity}_{setup}"
    sys, fibres, pwm = _bundle_system(k_fibres, n, p, fidelity, g, flow_law, groups, feed, name)
    ends = sum(end_mass(myo) for myo, _ in fibres)
    start = fibres[0][0].rest_length_expr
    if setup == "hanging":
        end = sys.add(Mass("load", m=HOOK_MASS_KG + load + ends, s_start=start))
        for _, mf in fibres:
            sys.connect(mf.flange_b, end.flange_a)
        return _flat(sys, pwm)
    if length is None:
        hung = bundle(
            k_fibres,
            n,
            p,
            fidelity,
            "hanging",
            0.0,
            None,
            regulator_tau,
            g,
            groups=groups,
        )  # where it hangs at rest at 0 Pa (on regulators: the same geometry)
        L = solve_equilibrium(hung, {})["load.s"]
    else:
        L = _arg(length, "m", "length", 0.0, True)
    hook = sys.add(Node("hook", m=HOOK_MASS_KG + ends, s_start=L))
    sensor = sys.add(ForceSensor("sensor"))
    fix = sys.add(Fixed("fixture", s0=L))
    for _, mf in fibres:
        sys.connect(mf.flange_b, hook.flange_a)
    sys.connect(hook.flange_a, sensor.flange_a)
    sys.connect(sensor.flange_b, fix.flange)
    return _flat(sys, pwm)


__all__ = [
    "MAX_FIBRES",
    "StiffnessOutput",
    "antagonistic_joint",
    "bundle",
    "supply_name",
    "stiffness_expression",
]
