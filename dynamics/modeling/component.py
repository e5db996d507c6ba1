"""Components declare parameters, variables, ports and equations through a Builder.

A component is a small Python class with a ``build(b)`` method. Inside it,
``b.parameter``, ``b.state``, ``b.variable``, ``b.input`` and ``b.port`` create CasADi
symbols named by the component's instance path (``"aps1.chamber.p"``); ``b.der``,
``b.equation`` and ``b.output`` state the physics. Composite components ``b.add``
children, ``b.connect`` their ports and ``b.expose`` inner ports as their own.
:class:`System` is the root composite: ``System.flatten()`` returns a
:class:`~sarcomere.dynamics.modeling.model.Model`.
"""

from __future__ import annotations

import math

import casadi as cs

from ..errors import ModelError
from .flatten import flatten
from .labels import NAME, NAME_RULE
from .model import Model
from .ports import Port, PortKind
from .variables import Collected, Kind, Var


def _sx(expr) -> cs.SX:
    """``expr`` as an SX (an SX itself, not a copy: a conversion costs as much as an
    arithmetic operation)."""
    return expr if isinstance(expr, cs.SX) else cs.SX(expr)


class Handle:
    """What ``Builder.add`` returns: a built child, giving access to its ports and symbols."""

    def __init__(self, path: str, ports: dict[str, Port], symbols: dict[str, cs.SX]) -> None:
        self.path = path
        self.ports = ports
        self.symbols = symbols

    def __getattr__(self, name: str) -> Port:
        ports = self.__dict__.get("ports", {})
        if name in ports:
            return ports[name]
        raise AttributeError(
            f"component '{self.__dict__.get('path')}' has no port '{name}'; "
            f"ports: {', '.join(ports) or 'none'}"
        )

    def sym(self, name: str) -> cs.SX:
        """The symbol of a variable of this child by its local name (e.g. ``"p"``)."""
        try:
            return self.symbols[name]
        except KeyError:
            raise ModelError(
                f"component '{self.path}' has no variable '{name}'; has: {', '.join(self.symbols)}"
            ) from None


class Builder:
    """The declaration API handed to ``Component.build``; one builder per instance path."""

    def __init__(self, collected: Collected, path: str) -> None:
        self._c = collected
        self.path = path
        self.ports: dict[str, Port] = {}
        self.symbols: dict[str, cs.SX] = {}
        self._children: set[str] = set()

    # --- declarations -------------------------------------------------------------
    def _full(self, local: str) -> str:
        return f"{self.path}.{local}" if self.path else local

    def _new(self, local: str, var: Var) -> cs.SX:
        if not NAME.match(local):
            raise ModelError(f"variable name '{local}' in '{self.path}' must be {NAME_RULE}")
        return self._declare(local, var)

    def _declare(self, local: str, var: Var) -> cs.SX:
        """A new symbol for ``var`` (named with its full path already)."""
        if local in self.symbols:
            raise ModelError(f"variable '{local}' declared twice in '{self.path}'")
        full = var.name
        sym = cs.SX.sym(full)
        self._c.variables[full] = var
        self._c.symbols[full] = sym
        self._c.children.setdefault(self.path, {})[local] = full
        self.symbols[local] = sym
        return sym

    def parameter(
        self,
        name: str,
        value: float,
        unit: str,
        description: str,
        low: float = -math.inf,
        high: float = math.inf,
        source: str = "",
        nominal: float | None = None,
    ) -> cs.SX:
        """A named model parameter [unit] with default ``value`` (checked against the range)
        and scaling magnitude ``nominal`` [unit] (default ``|value|``, or 1 for 0)."""
        value = float(value)
        var = Var(
            self._full(name),
            Kind.PARAMETER,
            unit=unit,
            description=description,
            start=value,
            low=low,
            high=high,
            value=value,
            source=source,
            nominal=nominal,
        )  # refuses a value outside [low, high]
        return self._new(name, var)

    def state(
        self, name: str, start: float | cs.SX, unit: str, description: str, **bounds
    ) -> cs.SX:
        """A state variable [unit]; give its derivative with :meth:`der`.

        ``start`` [unit]: a float or an expression of parameter symbols (see
        :meth:`set_start`). ``bounds``: ``low``, ``high`` (its physical range, default
        unbounded) and ``nominal`` (its scaling magnitude [unit], default ``|start|``
        at the parameter defaults, or 1 for 0).
        """
        return self._unknown(name, Kind.STATE, unit, description, start, **bounds)

    def variable(self, name: str, unit: str, description: str, start=0.0, **bounds) -> cs.SX:
        """An algebraic unknown [unit], fixed by the equations of the flattened system
        (``start``, ``bounds`` as for :meth:`state`)."""
        return self._unknown(name, Kind.ALGEBRAIC, unit, description, start, **bounds)

    def input(self, name: str, unit: str, description: str, start=0.0, **bounds) -> cs.SX:
        """An external input [unit] (a scenario signal or a controller drives it;
        ``start``, ``bounds`` as for :meth:`state`)."""
        return self._unknown(name, Kind.INPUT, unit, description, start, **bounds)

    def _unknown(
        self, name, kind, unit, description, start, low=-math.inf, high=math.inf, nominal=None
    ) -> cs.SX:
        full = self._full(name)
        start = self._start(full, start)
        self._track_nominal(full, start, nominal)
        return self._new(
            name,
            Var(
                full,
                kind,
                unit=unit,
                description=description,
                start=start,
                low=low,
                high=high,
                nominal=nominal,
            ),
        )

    def _start(self, full: str, start: float | cs.SX) -> float | cs.SX:
        """A start value as a float, or as an SX expression of declared parameters only."""
        if not isinstance(start, cs.SX | cs.MX | cs.DM):
            return float(start)
        if isinstance(start, cs.MX) or start.numel() != 1:
            raise ModelError(f"start value of '{full}' must be a scalar SX expression or float")
        if isinstance(start, cs.DM) or start.is_constant():
            return float(cs.DM(start))
        others = [
            s.name()
            for s in cs.symvar(start)
            if getattr(self._c.variables.get(s.name()), "kind", None) is not Kind.PARAMETER
            or self._c.symbols[s.name()].element_hash() != s.element_hash()  # the same node
        ]
        if others:
            raise ModelError(
                f"start value of '{full}' depends on {others}, which are not parameters; "
                "a start value may depend on parameters only"
            )
        return start

    def _track_nominal(self, full: str, start: float | cs.SX, nominal: float | None) -> None:
        """An expression start without a nominal: flattening sets the nominal to
        ``|start|`` at the parameter defaults (all such starts in one evaluation; ``Var``
        holds 1 until then). A float start: ``Var`` derives it."""
        if isinstance(start, cs.SX) and nominal is None:
            self._c.start_nominals[full] = start
        else:
            self._c.start_nominals.pop(full, None)

    def port(self, name: str, kind: PortKind) -> Port:
        """A connector with potential and flow unknowns named ``<path>.<name>.<var>``."""
        if name in self.ports:
            raise ModelError(f"port '{name}' declared twice in '{self.path}'")
        if not NAME.match(name):
            raise ModelError(f"port name '{name}' in '{self.path}' must be {NAME_RULE}")
        pot, flow = (
            self._declare(
                f"{name}.{var}",
                Var(self._full(f"{name}.{var}"), Kind.ALGEBRAIC, unit=unit, description=text),
            )
            for var, unit, text in (
                (kind.potential, kind.potential_unit, f"{kind.name} {name}: {kind.potential}"),
                (kind.flow, kind.flow_unit, f"{kind.name} {name}: {kind.flow} (into)"),
            )
        )
        p = Port(kind, f"{self.path}.{name}" if self.path else name, pot, flow)
        self.ports[name] = p
        self._c.ports.append(p)
        return p

    def set_start(self, sym: cs.SX, value: float | cs.SX, nominal: float | None = None) -> None:
        """Start value (or Newton guess, for an algebraic unknown) of a declared variable
        [its unit]: a float or an SX expression of parameter symbols, so that it follows
        a parameter change (e.g. an air mass ``V0 p_amb / (R T)``). The nominal value
        [unit] follows the new start unless given."""
        name = sym.name()
        start = self._start(name, value)
        self._track_nominal(name, start, nominal)
        var = self._c.variables[name]
        self._c.variables[name] = Var(**{**var.__dict__, "start": start, "nominal": nominal})

    def outer(self, name: str) -> dict[str, cs.SX]:
        """The parameter symbols of the top-level environment ``name`` (Modelica ``outer``).

        The environment is a component added once at the top of the System, before the
        components that use it (e.g. ``Environment("ambient")``); the result maps its local
        parameter names to their symbols, so every user shares one parameter each.
        """
        found = {
            local: self._c.symbols[full]
            for local, full in self._c.children.get(name, {}).items()
            if "." not in local and self._c.variables[full].kind == "parameter"
        }
        if not found:
            raise ModelError(
                f"'{self.path}' needs the environment '{name}', which is not declared: add it "
                f"at the top of the System first (e.g. sys.add(Environment('{name}')))"
            )
        return found

    # --- equations -----------------------------------------------------------------
    def der(self, state: cs.SX, rhs: cs.SX) -> None:
        """``d state / dt = rhs``."""
        name = state.name()
        if getattr(self._c.variables.get(name), "kind", None) is not Kind.STATE:
            raise ModelError(f"der() of '{name}', which is not a state")
        if name in self._c.ders:
            raise ModelError(f"derivative of '{name}' given twice")
        self._c.ders[name] = _sx(rhs)

    def der_of(self, name: str, expr: cs.SX, unit: str, description: str) -> cs.SX:
        """A variable equal to ``d expr / dt``, ``expr`` a function of the states only.

        Used where a transport element needs a velocity (a damper): flattening replaces
        it by ``d expr/dx . dx/dt`` once ``expr`` is known in terms of the states.
        """
        var = Var(self._full(name), Kind.DERIVATIVE, unit=unit, description=description)
        sym = self._new(name, var)
        self._c.time_derivatives[sym.name()] = _sx(expr)
        return sym

    def equation(self, lhs: cs.SX, rhs: cs.SX | float = 0.0) -> None:
        """``lhs == rhs`` (stored as the residual ``lhs - rhs``)."""
        lhs = _sx(lhs)
        sides = (lhs, rhs) if isinstance(rhs, cs.SX) else None
        self._c.equations.append((lhs - rhs, self.path or "<system>", sides))

    def output(
        self,
        name: str,
        expr: cs.SX,
        unit: str,
        description: str,
        low: float = -math.inf,
        high: float = math.inf,
        nominal: float = 1.0,
    ) -> None:
        """A named output ``<path>.<name>`` [unit] computed from the other variables.

        ``low``/``high`` bound its physical domain: equilibria and simulations that leave
        it are reported, not returned. ``nominal``: its scaling magnitude [unit].
        """
        full = self._full(name)
        if not NAME.match(name):
            raise ModelError(f"output name '{name}' in '{self.path}' must be {NAME_RULE}")
        if full in self._c.outputs or full in self._c.variables:
            raise ModelError(f"output '{full}' declared twice")
        self._c.variables[full] = Var(
            full,
            Kind.OUTPUT,
            unit=unit,
            description=description,
            low=low,
            high=high,
            nominal=nominal,
        )
        self._c.outputs[full] = _sx(expr)

    def energy(self, name: str, expr: cs.SX) -> None:
        """A stored energy term [J] (kinetic, potential, elastic or gas)."""
        self._c.energies[f"{self.path}.{name}"] = _sx(expr)

    def dissipation(self, name: str, expr: cs.SX) -> None:
        """A dissipated power term [W], >= 0 (damping, throttling)."""
        self._c.dissipations[f"{self.path}.{name}"] = _sx(expr)

    # --- composition ---------------------------------------------------------------
    def add(self, component: Component) -> Handle:
        """Build a child component under this path and return its handle."""
        child = Builder(self._c, f"{self.path}.{component.name}" if self.path else component.name)
        if component.name in self._children:
            raise ModelError(f"two components named '{component.name}' in '{self.path}'")
        self._children.add(component.name)
        component.build(child)
        return Handle(child.path, child.ports, child.symbols)

    def connect(self, a: Port, b: Port) -> None:
        """Connect two ports of the same kind: potentials equal, flows sum to zero."""
        if a.kind != b.kind:
            raise ModelError(f"cannot connect {a.path} ({a.kind.name}) to {b.path} ({b.kind.name})")
        self._c.connections.append((a, b))

    def expose(self, name: str, port: Port) -> None:
        """Make an inner port available as this component's port ``name``."""
        if name in self.ports:
            raise ModelError(f"port '{name}' declared twice in '{self.path}'")
        self.ports[name] = port


class Component:
    """Base class: subclasses store their settings in ``__init__`` and implement ``build``."""

    def __init__(self, name: str) -> None:
        if not NAME.match(name):
            raise ModelError(f"component name '{name}' must be {NAME_RULE}")
        self.name = name

    def build(self, b: Builder) -> None:  # pragma: no cover - abstract
        """Declare variables and equations on ``b``."""
        raise NotImplementedError


class System:
    """The root of a model: add components, connect them, then :meth:`flatten`.

    Examples
    --------
    >>> from sarcomere.dynamics.components.mechanical import Fixed, Mass, Spring
    >>> sys = System("oscillator")
    >>> fix = sys.add(Fixed("fix"))
    >>> spring = sys.add(Spring("spring", c=100.0))
    >>> mass = sys.add(Mass("mass", m=1.0, g=0.0))
    >>> sys.connect(fix.flange, spring.flange_a)
    >>> sys.connect(spring.flange_b, mass.flange_a)
    >>> model = sys.flatten()
    >>> model.state_names
    ['mass.s', 'mass.v']
    """

    def __init__(self, name: str) -> None:
        if not NAME.match(name):
            raise ModelError(f"system name '{name}' must be {NAME_RULE}")
        self.name = name
        self._c = Collected()
        self._root = Builder(self._c, "")

    def add(self, component: Component) -> Handle:
        """Add and build a top-level component."""
        return self._root.add(component)

    def connect(self, a: Port, b: Port) -> None:
        """Connect two ports (see :meth:`Builder.connect`)."""
        self._root.connect(a, b)

    def flatten(self) -> Model:
        """Flatten into one :class:`~sarcomere.dynamics.modeling.model.Model` (explicit ODE
        if possible)."""
        return flatten(self.name, self._c)
