"""Ready-made systems for the paper's experiments: hanging load and isometric fixture.

Each function builds a :class:`~sarcomere.dynamics.modeling.component.System`, flattens it and
returns the :class:`~sarcomere.dynamics.modeling.model.Model`. Stable signal names:

* ``regulator.p_cmd`` (input, Pa gauge), ``regulator.p_out`` (Pa gauge);
* ``myofibril.length`` (m), ``myofibril.apsK.chamber.p_gauge`` (Pa), ``myofibril.actinK.T`` (N);
* hanging load: ``load.s`` (m), ``load.m`` (parameter, kg);
* isometric: ``sensor.f`` (N), the force on the fixture.
"""

from __future__ import annotations

from .components.aps import CHAIN_LEVELS, APSParams, Myofibril, SymmetricMyofibril
from .components.mechanical import G_STANDARD, Fixed, ForceSensor, Mass, Spring
from .components.pneumatic import Regulator
from .errors import ParameterError
from .modeling.component import System
from .modeling.model import Model

HOOK_MASS_KG = 1.0e-3
"""Mass of the load hook and clip [kg] (estimate); the load mass adds to it, so the
"0 g" experiment still has a defined bottom end."""

FIDELITIES = (*CHAIN_LEVELS, "symmetric")
"""Dynamic fidelity levels (see :data:`CHAIN_LEVELS` and docs/model.md); "symmetric" is
one representative unit for n identical units."""


def _chain(n: int, p: APSParams, fidelity: str, g: float) -> Myofibril | SymmetricMyofibril:
    if fidelity not in FIDELITIES:
        raise ParameterError("fidelity", fidelity, f"one of {FIDELITIES}")
    if fidelity == "symmetric":
        return SymmetricMyofibril("myofibril", n, p, g=g)
    return Myofibril("myofibril", n, p, level=fidelity, g=g)


def _frame_regulator_chain(setup, n, params, fidelity, regulator_tau, g):
    """The part both set-ups share: the chain hung from the frame, fed by the regulator."""
    myo = _chain(n, params or APSParams.from_paper(), fidelity, g)
    sys = System(f"{setup}_n{n}_{fidelity}")
    frame = sys.add(Fixed("frame"))
    reg = sys.add(Regulator("regulator", tau=regulator_tau))
    mf = sys.add(myo)
    sys.connect(frame.flange, mf.flange_a)
    sys.connect(reg.port, mf.port)
    return sys, myo, mf


def hanging_load(
    n: int = 3,
    params: APSParams | None = None,
    load_kg: float = 0.0,
    fidelity: str = "full",
    regulator_tau: float = 0.05,
    g: float = G_STANDARD,
) -> Model:
    """Myofibril of ``n`` APS hanging from the frame, a load mass [kg] at its lower end."""
    if not load_kg >= 0:
        raise ParameterError("load_kg", load_kg, "[0, inf) kg")
    sys, myo, mf = _frame_regulator_chain("hanging", n, params, fidelity, regulator_tau, g)
    load = sys.add(Mass("load", m=HOOK_MASS_KG + load_kg, g=g, s_start=myo.rest_length))
    sys.connect(mf.flange_b, load.flange_a)
    return sys.flatten()


def isometric(
    n: int = 1,
    params: APSParams | None = None,
    fidelity: str = "full",
    fixture_stiffness: float | None = None,
    fixture_gap: float = 0.0,
    length: float | None = None,
    regulator_tau: float = 0.05,
    g: float = G_STANDARD,
) -> Model:
    """Myofibril between the frame and a force sensor on a fixture.

    ``fixture_stiffness`` None means rigid; otherwise a one-sided spring [N/m] with
    ``fixture_gap`` [m] of play. ``length`` [m] is the fixture position (default: the
    geometric rest length of the chain).
    """
    sys, myo, mf = _frame_regulator_chain("isometric", n, params, fidelity, regulator_tau, g)
    L = myo.rest_length if length is None else length
    if not L > 0:
        raise ParameterError("length", L, "(0, inf) m")
    sensor = sys.add(ForceSensor("sensor"))
    sys.connect(mf.flange_b, sensor.flange_a)
    if fixture_stiffness is None:
        fix = sys.add(Fixed("fixture", s0=L))
        sys.connect(sensor.flange_b, fix.flange)
    else:
        if not fixture_stiffness > 0:
            raise ParameterError("fixture_stiffness", fixture_stiffness, "(0, inf) N/m or None")
        # a tension spring from the chain end (above) down to the fixture at L: it
        # engages once the chain has lifted the hook by more than the gap
        anchor = sys.add(Fixed("fixture", s0=L))
        spring = sys.add(
            Spring("fixture_spring", c=fixture_stiffness, gap=fixture_gap, one_sided=True)
        )
        end = sys.add(Mass("hook", m=HOOK_MASS_KG, g=g, s_start=L))
        sys.connect(sensor.flange_b, end.flange_a)
        sys.connect(end.flange_b, spring.flange_a)
        sys.connect(spring.flange_b, anchor.flange)
    return sys.flatten()
