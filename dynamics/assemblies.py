"""Ready-made systems for the paper's experiments: hanging load and isometric fixture.

Each function builds a :class:`~sarcomere.dynamics.modeling.component.System`, flattens it and
returns the :class:`~sarcomere.dynamics.modeling.model.Model`. Stable signal names:

* ``regulator.p_cmd`` (input, Pa gauge, bounds ``[0, p_max]``), ``regulator.p_out`` (Pa gauge);
* ``myofibril.length`` (m), ``myofibril.apsK.chamber.p_gauge`` (Pa), ``myofibril.actinK.T`` (N);
* ``ambient.p``, ``ambient.T``, ``ambient.R``, ``ambient.gamma``, ``ambient.g``: the one
  environment every component shares (parameters);
* hanging load: ``load.s`` (m), ``load.m`` (parameter, kg);
* isometric: ``sensor.f`` (N), the force on the fixture; ``fixture.s0`` (m), its position.

Numeric arguments accept numbers in SI or quantity strings ("50 g", "5 ms"). A load or
APS parameters far from the paper's experiment get a
:class:`~.plausibility.PlausibilityWarning`.
"""

from __future__ import annotations

import functools
import inspect
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from .components.aps import APSParams
from .components.chains import (
    FLOW_LAWS,
    INSTANT_LEVELS,
    GroupedMyofibril,
    Myofibril,
    SymmetricMyofibril,
)
from .components.environment import Environment
from .components.mechanical import (
    Damper,
    Fixed,
    Force,
    ForceSensor,
    Mass,
    Node,
    Position,
    PositionSensor,
    Spring,
)
from .equilibrium import solve_equilibrium
from .errors import ParameterError
from .modeling.component import System
from .modeling.model import Model
from .params.ambient import Ambient
from .plausibility import PlausibilityWarning, implausible_aps, implausible_load
from .schema import FIDELITIES
from .supply import add_supply
from .units import to_si

HOOK_MASS_KG = 1.0e-3
"""Mass of the load hook and clip [kg] (estimate); the load mass adds to it, so the
"0 g" experiment still has a defined bottom end."""

GROUPS = 3
"""Groups of the "grouped" level: its cost is that of a chain of at most 6 units
whatever n."""

G_DEFAULT = Ambient().g
"""Default gravity of the set-ups [m/s^2] (the environment's default)."""


@dataclass(frozen=True)
class Setup:
    """How an assembly built a model (:attr:`Model.setup`): the function and every
    argument it was called with (defaults filled in), so the same set-up can be built
    again at another fidelity, flow law or clamp (a controller's prediction model)."""

    builder: Callable[..., Model]
    arguments: Mapping[str, object]

    def build(self, **changes) -> Model:
        """The set-up built again with ``changes`` to its arguments (e.g. ``fidelity``)."""
        return self.builder(**{**self.arguments, **changes})


def records_setup(builder: Callable[..., Model]) -> Callable[..., Model]:
    """``builder`` that records its :class:`Setup` on the model it returns."""
    signature = inspect.signature(builder)

    @functools.wraps(builder)
    def build(*args, **kwargs) -> Model:
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        model = builder(*args, **kwargs)
        model.setup = Setup(build, dict(bound.arguments))
        return model

    return build


def _si(value, unit: str, name: str, low: float, closed: bool = True) -> float:
    """A set-up argument in SI (numbers as given, quantity strings converted), checked
    against ``[low, inf)`` (``closed``) or ``(low, inf)``."""
    v = to_si(value, unit, name)
    if not (math.isfinite(v) and (v >= low if closed else v > low)):
        raise ParameterError(name, value, f"{'[' if closed else '('}{low:g}, inf) {unit}")
    return v


N_LIMITS = {
    "full": 175,
    "quasi_static": 60,
    "static_chain": 20,
    "grouped": 2000,
    "symmetric": 2000,
    "instant_pneumatics": 175,
    "instant_quasi_static": 60,
}
"""Longest chain each level handles, measured on a 50 g step (each well under a minute;
see ``N_WHY`` for what fails one step up). Set-ups refuse a longer chain at once."""

N_WHY = {
    "full": "its start equilibrium fails at n = 200 (no descent, also after 10 s of settling)",
    "quasi_static": "its massless elements form a loop of rates too large to solve past n = 60",
    "static_chain": "its equilibrium does not converge past about n = 20",
    "grouped": "its groups are symmetric chains; n = 2000 measured like 'symmetric'",
    "symmetric": "its start equilibrium fails at n = 5000",
    "instant_pneumatics": "its start equilibrium fails at n = 200 (n = 175: 9 s)",
    "instant_quasi_static": "as quasi_static: at n = 80 its loop of rates is refused",
}


def chain(n, p: APSParams, fidelity: str, flow_law: str, groups: int = GROUPS, name="myofibril"):
    """The chain of ``n`` units at ``fidelity`` (a component named ``name``), checked
    against the level's :data:`N_LIMITS`."""
    if fidelity not in FIDELITIES:
        raise ParameterError("fidelity", fidelity, f"one of {FIDELITIES}")
    if isinstance(n, int) and n > N_LIMITS[fidelity]:
        raise ParameterError(
            "n", n, f"[1, {N_LIMITS[fidelity]}] for the '{fidelity}' level", N_WHY[fidelity]
        )
    if flow_law not in FLOW_LAWS:
        raise ParameterError("flow_law", flow_law, f"one of {tuple(FLOW_LAWS)}")
    if fidelity == "grouped":
        return GroupedMyofibril(name, n, p, min(groups, n), flow_law)
    if fidelity == "symmetric":
        return SymmetricMyofibril(name, n, p, flow_law)
    if fidelity in INSTANT_LEVELS:
        return Myofibril(name, n, p, INSTANT_LEVELS[fidelity], flow_law, instant=True)
    return Myofibril(name, n, p, level=fidelity, flow_law=flow_law)


def end_mass(myo) -> float:
    """Chain body mass [kg] that rides on the mass at the chain end ("grouped" level)."""
    return myo.end_mass if isinstance(myo, GroupedMyofibril) else 0.0


def _frame_regulator_chain(
    setup,
    n,
    params,
    fidelity,
    regulator_tau,
    g,
    saturate,
    flow_law,
    groups=GROUPS,
    p_max=None,
    supply="regulator",
    valve=None,
):
    """The part both set-ups share: the environment, the chain hung from the frame, fed by
    its supply (:func:`~.supply.add_supply`: the regulator, ``p_max`` [Pa] its range's
    upper end, None the Regulator's default; or the PWM valve, options ``valve``); the
    supply's modulators go to the flattened model (:func:`_flat`)."""
    if params is not None and not isinstance(params, APSParams):
        raise ParameterError("params", params, "an APSParams or None (the paper's APS)")
    for name, why in implausible_aps(params or APSParams.from_paper()).items():
        warnings.warn(f"params.{name} = {why}", PlausibilityWarning, stacklevel=4)
    tau = _si(regulator_tau, "s", "regulator_tau", 0.0, closed=False)
    g = _si(g, "m/s^2", "g", 0.0, closed=False)
    myo = chain(n, params or APSParams.from_paper(), fidelity, flow_law, groups)
    sys = System(f"{setup}_n{n}_{fidelity}")
    sys.add(Environment(g=g))
    frame = sys.add(Fixed("frame"))
    p_max = None if p_max is None else _si(p_max, "Pa", "regulator_p_max", 0.0, False)
    name = "regulator" if supply == "regulator" else "valve"
    sup = add_supply(
        sys, name, supply, regulator_tau=tau, saturate=saturate, p_max=p_max, valve=valve
    )
    mf = sys.add(myo)
    sys.connect(frame.flange, mf.flange_a)
    sys.connect(sup.port, mf.port)
    sys.modulators = sup.modulators
    return sys, myo, mf


def _flat(sys: System) -> Model:
    """``sys`` flattened, carrying its supply's PWM (:attr:`Model.modulators`)."""
    model = sys.flatten()
    model.modulators.update(getattr(sys, "modulators", {}))
    return model


@records_setup
def hanging_load(
    n: int = 3,
    params: APSParams | None = None,
    load_kg: float | str = 0.0,
    fidelity: str = "full",
    regulator_tau: float | str = 0.05,
    g: float | str = G_DEFAULT,
    saturate: bool = True,
    flow_law: str = "iso6358",
    groups: int = GROUPS,
    regulator_p_max: float | str | None = None,
    supply: str = "regulator",
    valve: Mapping[str, object] | None = None,
) -> Model:
    """Myofibril of ``n`` APS hanging from the frame, a load mass [kg] at its lower end.

    ``saturate``: the regulator clamps its command to ``[0, p_max]`` (plants; False for
    optimisers, which use the input's bounds). ``flow_law``: "iso6358" (exact) or
    "smooth" (C1, for optimisers). ``groups``: of the "grouped" level.
    ``regulator_p_max`` [Pa]: the regulator's range (the input's bound and the clamp);
    None: the Regulator's default (6 bar). ``supply``: "regulator" or "valve_pwm" (a
    PWM-driven on/off valve named ``valve``, input ``valve.cmd`` the duty cycle;
    ``valve`` its options, :class:`~.supply.ValveOptions`; docs/model.md).
    """
    load = _si(load_kg, "kg", "load_kg", 0.0)
    if why := implausible_load(load):
        warnings.warn(f"load_kg = {why}", PlausibilityWarning, stacklevel=3)
    sys, myo, mf = _frame_regulator_chain(
        "hanging",
        n,
        params,
        fidelity,
        regulator_tau,
        g,
        saturate,
        flow_law,
        groups,
        regulator_p_max,
        supply,
        valve,
    )
    end = sys.add(Mass("load", m=HOOK_MASS_KG + load + end_mass(myo), s_start=myo.rest_length_expr))
    sys.connect(mf.flange_b, end.flange_a)
    return _flat(sys)


def hanging_rest_position(
    n: int = 1,
    params: APSParams | None = None,
    fidelity: str = "full",
    g: float | str = G_DEFAULT,
    groups: int = GROUPS,
) -> float:
    """Position [m] of the chain's hook below the frame when it hangs at rest at 0 MPa with
    no load (the 1 g hook only): where the isometric experiment attaches its sensor."""
    model = hanging_load(n, params, 0.0, fidelity, g=g, groups=groups)
    return solve_equilibrium(model, {"regulator.p_cmd": 0.0})["load.s"]


@records_setup
def isometric(
    n: int = 1,
    params: APSParams | None = None,
    fidelity: str = "full",
    fixture_stiffness: float | str | None = None,
    fixture_gap: float | str = 0.0,
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
    """Myofibril between the frame and a force sensor on a fixture.

    As in the experiment, the chain first hangs at rest at 0 MPa (with its 1 g hook), and
    the sensor is attached there without pre-tension: the fixture position ``length``
    [m] defaults to :func:`hanging_rest_position` (the model's own equilibrium), so the
    sensor reads zero at 0 MPa. ``fixture_stiffness`` None means rigid; otherwise a
    one-sided spring [N/m] with ``fixture_gap`` [m] of play. ``saturate``,
    ``flow_law``, ``groups``, ``regulator_p_max``, ``supply`` and ``valve`` as
    :func:`hanging_load`.
    """
    if length is None:
        L = hanging_rest_position(n, params, fidelity, g, groups)
    else:
        L = _si(length, "m", "length", 0.0, closed=False)
    gap = _si(fixture_gap, "m", "fixture_gap", 0.0)
    if gap > 0 and fixture_stiffness is None:
        raise ParameterError(
            "fixture_gap", fixture_gap, "0 with a rigid fixture", "play needs fixture_stiffness"
        )
    sys, myo, mf = _frame_regulator_chain(
        "isometric",
        n,
        params,
        fidelity,
        regulator_tau,
        g,
        saturate,
        flow_law,
        groups,
        regulator_p_max,
        supply,
        valve,
    )
    sensor = sys.add(ForceSensor("sensor"))
    fix = sys.add(Fixed("fixture", s0=L))
    if fixture_stiffness is None:
        hook = sys.add(Node("hook", m=HOOK_MASS_KG + end_mass(myo), s_start=L))
        sys.connect(mf.flange_b, hook.flange_a)
        sys.connect(mf.flange_b, sensor.flange_a)
        sys.connect(sensor.flange_b, fix.flange)
    else:
        k = _si(fixture_stiffness, "N/m", "fixture_stiffness", 0.0, closed=False)
        # a tension spring from the hook (above) down to the fixture at L: it engages once
        # the chain has lifted the hook by more than the gap
        spring = sys.add(Spring("fixture_spring", c=k, gap=gap, one_sided=True))
        hook = sys.add(Mass("hook", m=HOOK_MASS_KG + end_mass(myo), s_start=L))
        sys.connect(mf.flange_b, hook.flange_a)
        sys.connect(hook.flange_b, sensor.flange_a)
        sys.connect(sensor.flange_b, spring.flange_a)
        sys.connect(spring.flange_b, fix.flange)
    return _flat(sys)


SPRING_LOAD = {"mass_kg": 0.05, "stiffness": 100.0, "damping": 0.5}
"""Defaults of the sprung load [kg, N/m, N*s/m]: step-50g's 50 g, hung on a spring whose
load mode (sqrt(k/m) = 45 rad/s, 7 Hz) sits near the hanging chain's own load mode
(6.7 Hz, docs/controllers.md), lightly damped to the ground (damping ratio 0.16); chosen
for the co-simulation scene ``cosim-controller-load``, not measured."""


def force_driven(
    n: int = 3,
    params: APSParams | None = None,
    fidelity: str = "full",
    regulator_tau: float | str = 0.05,
    g: float | str = G_DEFAULT,
    saturate: bool = True,
    flow_law: str = "iso6358",
    hook_kg: float | str = HOOK_MASS_KG,
) -> Model:
    """Myofibril of ``n`` APS hanging from the frame, its lower end (the hook, ``hook_kg``
    [kg], default 1 g) free and pulled down by the input force ``pull.f`` [N, along +s];
    output ``end.s`` [m], the end's position below the frame. The muscle of a
    co-simulation whose load is another participant (its force in, the end position out);
    other arguments as :func:`hanging_load`."""
    sys, myo, mf = _frame_regulator_chain(
        "force_driven", n, params, fidelity, regulator_tau, g, saturate, flow_law
    )
    _hook_pulled(sys, myo, mf, sys.add(Force("pull")).flange, hook_kg)
    return sys.flatten()


def _hook_pulled(sys: System, myo, mf, flange, hook_kg) -> None:
    """The hook [kg] at the chain's end, with the end-position sensor, attached to
    ``flange``."""
    m = _si(hook_kg, "kg", "hook_kg", 0.0, closed=False) + end_mass(myo)
    hook = sys.add(Mass("hook", m=m, s_start=myo.rest_length_expr))
    sys.connect(mf.flange_b, hook.flange_a)
    sys.connect(hook.flange_b, sys.add(PositionSensor("end")).flange)
    sys.connect(hook.flange_b, flange)


def _spring_load(sys: System, mass_kg, stiffness, damping, g, s_start, rest_length) -> object:
    """Force sensor, spring (unstretched length ``rest_length`` [m]) and mass (damped to
    the ground) below a flange; returns the sensor's upper flange. ``sensor.f`` [N] is the
    force the load pulls with."""
    m = _si(mass_kg, "kg", "mass_kg", 0.0, closed=False)
    k = _si(stiffness, "N/m", "stiffness", 0.0, closed=False)
    d = _si(damping, "N*s/m", "damping", 0.0)
    g = _si(g, "m/s^2", "g", 0.0, closed=False)
    rest = _si(rest_length, "m", "rest_length", 0.0)
    sensor = sys.add(ForceSensor("sensor"))
    spring = sys.add(Spring("spring", c=k, s_rel0=rest))
    mass = sys.add(Mass("mass", m=m, g=g, s_start=s_start + rest))
    damper = sys.add(Damper("damper", d=d))
    ground = sys.add(Fixed("ground"))
    sys.connect(sensor.flange_b, spring.flange_a)
    sys.connect(spring.flange_b, mass.flange_a)
    sys.connect(ground.flange, damper.flange_a)
    sys.connect(damper.flange_b, mass.flange_b)
    return sensor.flange_a


def spring_mass_load(
    mass_kg: float | str = SPRING_LOAD["mass_kg"],
    stiffness: float | str = SPRING_LOAD["stiffness"],
    damping: float | str = SPRING_LOAD["damping"],
    g: float | str = G_DEFAULT,
    rest_length: float | str = 0.0,
) -> Model:
    """A mass [kg] hanging on a spring [N/m, unstretched length ``rest_length`` m] whose
    top is moved to the input position ``drive.s`` [m]; a damper [N*s/m] from the mass to
    the ground. Output ``sensor.f`` [N], the tension at the top (the load's pull on
    whatever holds it). The load of :func:`force_driven` as a model of its own (defaults
    :data:`SPRING_LOAD`)."""
    sys = System("spring_mass_load")
    drive = sys.add(Position("drive"))
    top = _spring_load(sys, mass_kg, stiffness, damping, g, 0.0, rest_length)
    sys.connect(drive.flange, top)
    return sys.flatten()


def sprung_load(
    n: int = 3,
    params: APSParams | None = None,
    fidelity: str = "full",
    regulator_tau: float | str = 0.05,
    g: float | str = G_DEFAULT,
    mass_kg: float | str = SPRING_LOAD["mass_kg"],
    stiffness: float | str = SPRING_LOAD["stiffness"],
    damping: float | str = SPRING_LOAD["damping"],
    hook_kg: float | str = HOOK_MASS_KG,
    rest_length: float | str = 0.0,
    saturate: bool = True,
    flow_law: str = "iso6358",
) -> Model:
    """:func:`force_driven` with :func:`spring_mass_load` hung from its hook, in one model
    (the monolithic reference of their co-simulation; the same names but ``pull.f`` and
    ``drive.s``); ``saturate`` and ``flow_law`` as :func:`hanging_load` (an NMPC's
    prediction: ``flow_law="smooth", saturate=False``)."""
    sys, myo, mf = _frame_regulator_chain(
        "sprung_load", n, params, fidelity, regulator_tau, g, saturate, flow_law
    )
    top = _spring_load(sys, mass_kg, stiffness, damping, g, myo.rest_length_expr, rest_length)
    _hook_pulled(sys, myo, mf, top, hook_kg)
    return sys.flatten()
