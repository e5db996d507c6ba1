"""The scene binding of the robot set-ups (:mod:`sarcomere.dynamics.robots`):
``[model] name = "joint"`` (the antagonistic joint) or ``"bundle"`` (parallel fibres).

:func:`~.binding.bind` reads ``[parameters]`` as for a chain (``aps.<field>`` for every
unit, ``regulator.p_max`` for every regulator, any other key a model parameter path such
as ``"joint.r"`` or ``"joint.tau_load"``) and hands the rest here. ``[model] n`` is the
units per chain (the flexor's, and each fibre's); ``fidelity`` one of the dynamic
levels (``"auto"`` and the levels without a model of their own are refused: they
read one chain's one command). ``[model.options]``:

- joint: ``n_extensor`` (default n), ``tendon_length`` ("20 mm"), ``regulator_tau``,
  ``flow_law``, ``supply`` (``"regulator"`` or ``"valve_pwm"``: each muscle on a PWM
  valve with :class:`~sarcomere.dynamics.supply.ValveOptions`' defaults, its command the
  duty cycle ``<side>_valve.cmd``);
- bundle: ``fibres`` (k, default 3), ``setup`` (``"hanging"`` or ``"isometric"``),
  ``load`` (hanging only), ``regulator_tau``, ``flow_law``, ``supply``.
"""

from __future__ import annotations

import dataclasses

from sarcomere.dynamics.assemblies import GROUPS
from sarcomere.dynamics.components.aps import APSParams
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.robots import antagonistic_joint, bundle, supply_name
from sarcomere.dynamics.schema import WITHOUT_MODEL
from sarcomere.dynamics.units import to_si

from .spec import Scenario, check_overrides, describe, unknown_key

ROBOT_MODELS = ("joint", "bundle")
"""``[model] name`` values of the robot set-ups."""

_COMMON = {"regulator_tau": "s", "flow_law": "", "supply": ""}
OPTIONS = {
    "joint": {"n_extensor": "count", "tendon_length": "m", **_COMMON},
    "bundle": {"fibres": "count", "setup": "", "load": "kg", **_COMMON},
}
"""``[model.options]`` of each robot model -> SI unit ("" text, "count" an integer)."""

#: option -> the set-up argument it becomes (where it is not the same name)
_ARGUMENT = {"fibres": "k_fibres", "load": "load_kg"}


def robot_options(sc: Scenario) -> dict:
    """``[model.options]`` of a robot model in SI, each key checked; also refuses the
    levels that do not apply."""
    name = sc.model.name
    fid = sc.model.fidelity
    if fid == "auto" or fid in WITHOUT_MODEL:
        raise sc.error(
            ("model", "fidelity"),
            f"'{fid}' is not available for model '{name}': it reads one chain and its one "
            "pressure command, and a robot set-up has a chain and a command per muscle; "
            "set a dynamic level (full, quasi_static, symmetric, ...)",
        )
    out = {}
    for key, raw in sc.model.options.items():
        if key not in OPTIONS[name]:
            raise sc.error(("model", "options", key), unknown_key(key, list(OPTIONS[name])))
        unit = OPTIONS[name][key]
        if unit == "count":
            if isinstance(raw, bool) or not isinstance(raw, int) or raw < 1:
                raise sc.error(("model", "options", key), f"{raw!r}: expected an integer >= 1")
            value = raw
        elif unit == "":
            if not isinstance(raw, str):
                raise sc.error(("model", "options", key), f"{raw!r}: expected a string")
            value = raw
        else:
            try:
                value = to_si(raw, unit, key, bare_ok=False)
            except ParameterError as exc:
                raise sc.error(("model", "options", key), describe(exc)) from None
        out[_ARGUMENT.get(key, key)] = value
    if out.get("setup") == "isometric" and "load_kg" in out:
        raise sc.error(("model", "options", "load"), "set-up 'isometric' does not use 'load'")
    return out


@dataclasses.dataclass(frozen=True)
class RobotBinding:
    """A robot scene's model settings in SI (the :class:`~.binding.Binding` interface:
    :meth:`build`, ``n``, ``aps``, ``setup``, ``overrides``, ``scenario``)."""

    model: str
    n: int
    aps: APSParams
    options: dict
    overrides: dict
    regulator_p_max: float | None = None
    scenario: Scenario | None = dataclasses.field(default=None, compare=False, repr=False)
    load_kg: float = 0.0

    @property
    def setup(self) -> str:
        """``"joint"``, ``"bundle-hanging"`` or ``"bundle-isometric"``."""
        if self.model == "joint":
            return "joint"
        return f"bundle-{self.options.get('setup', 'hanging')}"

    @property
    def supply(self) -> str:
        """The chains' supply: ``"regulator"`` or ``"valve_pwm"``."""
        return self.options.get("supply", "regulator")

    @property
    def inputs(self) -> list[str]:
        """The commands of the model built, one per chain (a regulator's pressure or a
        valve's duty cycle)."""
        cmd = "p_cmd" if self.supply == "regulator" else "cmd"
        chains = (
            ["flexor", "extensor"]
            if self.model == "joint"
            else [f"fibre{i}" for i in range(1, self.options.get("k_fibres", 3) + 1)]
        )
        return [f"{supply_name(c, self.supply)}.{cmd}" for c in chains]

    def require_regulators(self, kind: str) -> None:
        """Refuse the valve supply for a kind that commands pressures."""
        if self.supply != "regulator" and self.scenario is not None:
            raise self.scenario.error(
                ("model", "options", "supply"),
                f"kind '{kind}' commands pressures (regulators); the valve's command is a "
                "duty cycle: use a transient for supply = 'valve_pwm'",
            )

    def build(
        self,
        fidelity: str,
        n: int | None = None,
        flow_law: str | None = None,
        saturate: bool = True,
        groups: int = GROUPS,
    ) -> Model:
        """The set-up at ``fidelity`` (as :meth:`.binding.Binding.build`)."""
        kw = {**self.options, "saturate": saturate, "groups": groups}
        if flow_law is not None:
            kw["flow_law"] = flow_law
        if self.regulator_p_max is not None:
            kw["regulator_p_max"] = self.regulator_p_max
        n = self.n if n is None else n
        try:
            if self.model == "joint":
                model = antagonistic_joint(n, params=self.aps, fidelity=fidelity, **kw)
            else:
                model = bundle(n=n, params=self.aps, fidelity=fidelity, **kw)
        except ParameterError as exc:
            if self.scenario is None:
                raise
            arg = {v: k for k, v in _ARGUMENT.items()}.get(exc.name, exc.name)
            path = ("model", "options", arg) if arg in OPTIONS[self.model] else ("model",)
            raise self.scenario.error(path, describe(exc)) from None
        check_overrides(self.scenario, self.overrides, model)
        return model


__all__ = ["OPTIONS", "ROBOT_MODELS", "RobotBinding", "robot_options"]
