"""A muscle's air supply, for any set-up: the proportional regulator, or a 3/2 (or 2/2)
on/off valve driven by PWM from a pressure source through a hose.

:func:`add_supply` adds the supply's components to a :class:`System` and returns a
:class:`Supply`: the pneumatic port to connect to the muscle's manifold, the name of the
command input, and the PWM that the flattened model carries for it (set
``model.modulators.update(supply.modulators)`` after flattening). Names, for a supply
called ``name``:

* ``"regulator"``: the :class:`~.components.pneumatic.Regulator` ``name``, input
  ``name.p_cmd`` [Pa gauge], output ``name.p_out``;
* ``"valve_pwm"``: the source ``name_source`` (``.p_supply``, its flow ``.m_flow``
  [kg/s], whose integral is the air used, and ``.power`` [W]), the valve ``name``
  (input ``name.cmd`` [1]: the duty cycle 0-1, which the PWM turns into the on/off
  command; valve state ``name.x``, the opening), the hose ``name_hose`` (a fixed
  volume: ``.p_gauge``, ``.m_air``) on a mount.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

from .components.mechanical import Fixed
from .components.pneumatic import Chamber, Regulator
from .components.valve import C_LEAK, C_OPEN, WAYS, PressureSource, SwitchingValve
from .errors import ParameterError
from .modeling.component import System
from .modeling.ports import Port
from .simulation.pwm import LEVELS, PWM
from .units import to_si

SUPPLIES = ("regulator", "valve_pwm")
"""Supply kinds of the set-ups."""


@dataclass(frozen=True)
class ValveOptions:
    """The PWM valve supply's settings, SI (each with its default and source).

    Attributes
    ----------
    ways : str
        "3/2" (default: fills and vents) or "2/2" (fills only; the muscle then keeps its
        air).
    frequency : float
        PWM frequency [Hz], default 50 (:class:`~.simulation.pwm.PWM`).
    min_on : float
        Minimum on-time [s], default 0.
    delay : float
        Switching delay [s], default 1 ms (estimate: the coil current's rise before the
        armature moves, fast-switching valves).
    tau : float
        Opening time [s], default 1.5 ms (:class:`~.components.valve.SwitchingValve`).
    p_supply : float
        Supply gauge pressure [Pa], default 0.3 MPa (:class:`~.components.valve.PressureSource`).
    C_open, C_leak, b : float
        Open and closed sonic conductance [m^3/(s Pa)], critical ratio [1].
    hose_volume : float
        Volume of the hose and manifold between valve and muscle [m^3], default 3 cm^3
        (0.25 m of 4 mm bore tube; estimate).
    level : str
        "switched" (the pulses) or "averaged" (their duty-weighted mean), :data:`LEVELS`.
    """

    ways: str = "3/2"
    frequency: float = 50.0
    min_on: float = 0.0
    delay: float = 1.0e-3
    tau: float = 1.5e-3
    p_supply: float = 3.0e5
    C_open: float = C_OPEN
    C_leak: float = C_LEAK
    b: float = 0.3
    hose_volume: float = 3.0e-6
    level: str = "switched"

    @classmethod
    def from_mapping(cls, options: Mapping[str, object] | None) -> ValveOptions:
        """Options from a mapping (numbers in SI or quantity strings), checked."""
        if isinstance(options, ValveOptions):
            return options
        options = dict(options or {})
        units = dict(UNITS)
        unknown = sorted(set(options) - set(units))
        if unknown:
            raise ParameterError("valve", unknown, f"valve options {sorted(units)}")
        out = {}
        for key, value in options.items():
            if units[key] is None:
                out[key] = value
            else:
                out[key] = to_si(value, units[key], f"valve.{key}")
        return cls(**out)

    def __post_init__(self) -> None:
        if self.ways not in WAYS:
            raise ParameterError("valve.ways", self.ways, f"one of {WAYS}")
        if self.level not in LEVELS:
            raise ParameterError("valve.level", self.level, f"one of {LEVELS}")
        for name in ("tau", "p_supply", "C_open", "hose_volume"):
            v = getattr(self, name)
            if not v > 0:
                raise ParameterError(f"valve.{name}", v, f"(0, inf) {UNITS[name]}")
        self.pwm()  # checks frequency, min_on, delay

    def pwm(self) -> PWM:
        """The modulator of the valve's command."""
        return PWM(self.frequency, self.min_on, self.delay, self.level)


UNITS = {
    "ways": None,
    "frequency": "Hz",
    "min_on": "s",
    "delay": "s",
    "tau": "s",
    "p_supply": "Pa",
    "C_open": "m^3/(s*Pa)",
    "C_leak": "m^3/(s*Pa)",
    "b": "1",
    "hose_volume": "m^3",
    "level": None,
}
"""The SI unit of each :class:`ValveOptions` field (None: not a quantity)."""

assert set(UNITS) == {f.name for f in fields(ValveOptions)}


@dataclass
class Supply:
    """What :func:`add_supply` added: the port to the muscle, the command input's name
    and the modulators the flattened model must carry."""

    port: Port
    command: str
    modulators: dict = field(default_factory=dict)


def add_supply(
    sys: System,
    name: str,
    supply: str = "regulator",
    *,
    regulator_tau: float = 0.05,
    saturate: bool = True,
    p_max: float | None = None,
    valve: Mapping[str, object] | ValveOptions | None = None,
) -> Supply:
    """Add a muscle's supply ``supply`` (:data:`SUPPLIES`) called ``name`` to ``sys``.

    ``regulator_tau`` [s], ``saturate`` and ``p_max`` [Pa] (None: the Regulator's
    default) configure the regulator; ``valve`` (a mapping of :class:`ValveOptions`
    fields, or one) the valve supply. Settings of the other kind are refused.
    """
    if supply not in SUPPLIES:
        raise ParameterError("supply", supply, f"one of {SUPPLIES}")
    if supply == "regulator":
        if valve:
            raise ParameterError("valve", valve, "no valve options with supply = 'regulator'")
        extra = {} if p_max is None else {"p_max": p_max}
        reg = sys.add(Regulator(name, tau=regulator_tau, saturate=saturate, **extra))
        return Supply(reg.port, f"{name}.p_cmd")
    if p_max is not None:
        raise ParameterError(
            "regulator_p_max", p_max, "None with supply = 'valve_pwm'", "there is no regulator"
        )
    opts = ValveOptions.from_mapping(valve)
    source = sys.add(PressureSource(f"{name}_source", p_supply=opts.p_supply))
    v = sys.add(
        SwitchingValve(
            name,
            ways=opts.ways,
            C_open=opts.C_open,
            C_leak=opts.C_leak,
            b=opts.b,
            tau=opts.tau,
            smooth=not saturate,
        )
    )
    hose = sys.add(Chamber(f"{name}_hose", V0=opts.hose_volume, A=0.0))
    mount = sys.add(Fixed(f"{name}_mount"))
    sys.connect(mount.flange, hose.flange)
    sys.connect(source.port, v.port_p)
    sys.connect(v.port_a, hose.port)
    return Supply(hose.port, f"{name}.cmd", {f"{name}.cmd": opts.pwm()})


__all__ = ["SUPPLIES", "Supply", "ValveOptions", "add_supply"]
