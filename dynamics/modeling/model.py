"""The flattened model: named variables and plain CasADi Functions.

Every later stage (simulation, equilibrium, linearisation, MPC, FMU export) uses only
what this class exposes: the symbol vectors ``x`` (states), ``z`` (algebraic unknowns
left after elimination), ``u`` (inputs), ``p`` (parameters), the expressions ``ode``,
``alg``, ``y`` (declared outputs), and Functions built from them with named inputs and
outputs (``model.function("ode")(x=..., z=..., u=..., p=...)["ode"]``). There is no
second copy of the physics anywhere.
"""

from __future__ import annotations

import difflib
import functools
import math
from collections.abc import Mapping, Sequence
from types import MappingProxyType

import casadi as cs
import numpy as np

from ..errors import ParameterError
from ..units import to_si
from .variables import Var

_ARGS = ["x", "z", "u", "p"]


class Model:
    """A flattened semi-explicit DAE ``dx/dt = f(x, z, u, p)``, ``0 = g(x, z, u, p)``.

    Attributes
    ----------
    state_names, alg_names, input_names, param_names, output_names : list of str
        Variable paths in vector order, e.g. ``"aps1.chamber.m_air"``.
    variables : read-only mapping of str to Var
        Unit, start value, bounds, description (and default value for parameters);
        the Model's own copy, unaffected by later changes to the System.
    setup : object or None
        How an assembly built it (:class:`~sarcomere.dynamics.assemblies.Setup`:
        ``setup.build(fidelity=...)`` builds the same set-up again); None for a
        System flattened by hand.
    modulators : dict
        Input name to the :class:`~sarcomere.dynamics.simulation.pwm.PWM` that the
        simulator puts between that input (a duty cycle) and the equations (an on/off
        valve's command); empty for most models.
    """

    def __init__(
        self,
        name: str,
        variables: dict[str, Var],
        symbols: dict[str, cs.SX],
        ders: dict[str, cs.SX],
        alg: list[cs.SX],
        alg_vars: list[str],
        solved: dict[str, cs.SX],
        outputs: dict[str, cs.SX],
        energies: dict[str, cs.SX],
        dissipations: dict[str, cs.SX],
    ) -> None:
        self.name = name
        self.setup = None
        self.modulators: dict = {}
        self.variables: Mapping[str, Var] = MappingProxyType(dict(variables))
        self.state_names = [v for v, m in variables.items() if m.kind == "state"]
        self.alg_names = list(alg_vars)
        self.input_names = [v for v, m in variables.items() if m.kind == "input"]
        self.param_names = [v for v, m in variables.items() if m.kind == "parameter"]
        self.output_names = list(outputs)
        vec = [symbols[n] for n in self.state_names]
        self.x = cs.vertcat(*vec) if vec else cs.SX(0, 1)
        self.z = cs.vertcat(*[symbols[n] for n in self.alg_names]) if alg_vars else cs.SX(0, 1)
        ins = [symbols[n] for n in self.input_names]
        self.u = cs.vertcat(*ins) if ins else cs.SX(0, 1)
        pars = [symbols[n] for n in self.param_names]
        self.p = cs.vertcat(*pars) if pars else cs.SX(0, 1)
        self.ode = cs.vertcat(*[ders[n] for n in self.state_names]) if vec else cs.SX(0, 1)
        self.alg = cs.vertcat(*alg) if alg else cs.SX(0, 1)
        self.y = cs.vertcat(*outputs.values()) if outputs else cs.SX(0, 1)
        # Every named signal as an expression of (x, z, u, p): for result tables.
        sig = {n: symbols[n] for n in self.state_names + self.alg_names + self.input_names}
        sig.update(solved)
        sig.update(outputs)
        order = [n for n in variables if n in sig]
        self.signal_names = order
        self._signals = cs.vertcat(*[sig[n] for n in order])
        self._energies = energies
        self._dissipations = dissipations

    # --- sizes and defaults --------------------------------------------------------
    @property
    def nx(self) -> int:
        """Number of states."""
        return self.x.numel()

    @property
    def nz(self) -> int:
        """Number of algebraic unknowns left after elimination (0 for an explicit ODE)."""
        return self.z.numel()

    def unit(self, name: str) -> str:
        """SI unit of a variable."""
        return self.variables[name].unit

    def x0(self, p: np.ndarray | None = None) -> np.ndarray:
        """Start values of the states at the parameter vector ``p`` (default: the
        parameter defaults); start values that are parameter expressions follow ``p``."""
        return self._start(p, "x0")

    def z0(self, p: np.ndarray | None = None) -> np.ndarray:
        """Start guesses of the algebraic unknowns at ``p`` (default: parameter defaults)."""
        return self._start(p, "z0")

    def u0(self, p: np.ndarray | None = None) -> np.ndarray:
        """Start values of the inputs at ``p`` (default: parameter defaults)."""
        return self._start(p, "u0")

    def _start(self, p: np.ndarray | None, which: str) -> np.ndarray:
        pv = self.parameters() if p is None else p
        return np.array(self.function("start")(p=pv)[which], dtype=float).reshape(-1)

    def nominal(self, which: str) -> np.ndarray:
        """Nominal values (scaling magnitudes, > 0, in each variable's unit) of the vector
        ``which``: "x", "z", "u", "p" or "y"."""
        names = {
            "x": self.state_names,
            "z": self.alg_names,
            "u": self.input_names,
            "p": self.param_names,
            "y": self.output_names,
        }
        if which not in names:
            raise ParameterError("which", which, "one of 'x', 'z', 'u', 'p', 'y'")
        return np.array([self.variables[n].nominal for n in names[which]], dtype=float)

    def parameters(self, overrides: Mapping[str, object] | None = None) -> np.ndarray:
        """The parameter vector (defaults, then ``overrides`` by name; units allowed).

        Raises
        ------
        ParameterError
            For an unknown name or a value outside the parameter's range.
        """
        values = {n: self.variables[n].value for n in self.param_names}
        for key, raw in (overrides or {}).items():
            if key not in values:
                close = difflib.get_close_matches(key, self.param_names, n=3)
                hint = f"did you mean {close}?" if close else f"{len(values)} parameters exist"
                raise ParameterError(key, raw, f"a parameter of model '{self.name}'", hint)
            var = self.variables[key]
            val = to_si(raw, var.unit, key)
            if not var.contains(val):
                raise var.refuse(key, raw)
            values[key] = val
        return np.array([values[n] for n in self.param_names], dtype=float)

    def index(self, name: str) -> tuple[str, int]:
        """Which vector (``"x"``, ``"z"``, ``"u"``, ``"p"``, ``"y"``) holds ``name``, and where."""
        for vec, names in (
            ("x", self.state_names),
            ("z", self.alg_names),
            ("u", self.input_names),
            ("p", self.param_names),
            ("y", self.output_names),
        ):
            if name in names:
                return vec, names.index(name)
        raise KeyError(f"model '{self.name}' has no variable '{name}'")

    # --- CasADi Functions ----------------------------------------------------------
    @functools.cached_property
    def _syms(self) -> list[cs.SX]:
        return [self.x, self.z, self.u, self.p]

    def function(self, which: str) -> cs.Function:
        """A CasADi Function of (x, z, u, p) with named inputs and outputs.

        ``which`` is one of "ode", "alg", "y" (declared outputs), "signals" (every
        named variable, in :attr:`signal_names` order), "energy" (stored energies [J]
        and dissipated powers [W], summed as ``E`` and ``D``), "jac" (``A, B, C, D`` of
        :meth:`linearization` for the declared outputs ``y``, with ``z`` eliminated),
        "dae_jac" (``ode_x, ode_z, alg_x, alg_z``), and "start", a Function of ``p``
        alone giving the start values ``x0``, ``z0``, ``u0``.
        """
        cache = self.__dict__.setdefault("_functions", {})
        if which not in cache:
            cache[which] = self._build_function(which)
        return cache[which]

    def _build_function(self, which: str) -> cs.Function:
        s = self._syms
        if which in ("ode", "alg", "y", "signals"):
            expr = {"ode": self.ode, "alg": self.alg, "y": self.y, "signals": self._signals}
            return cs.Function(which, s, [expr[which]], _ARGS, [which])
        if which == "energy":
            e = cs.vertcat(*self._energies.values()) if self._energies else cs.SX(0, 1)
            d = cs.vertcat(*self._dissipations.values()) if self._dissipations else cs.SX(0, 1)
            return cs.Function(
                "energy", s, [cs.sum1(e), cs.sum1(d), e, d], _ARGS, ["E", "D", "terms", "dterms"]
            )
        if which == "jac":
            return self._linear("jacobians", self.y)
        if which == "dae_jac":
            return cs.Function(
                "dae_jac",
                s,
                [
                    self._jacobian("ode", "x"),
                    self._jacobian("ode", "z"),
                    self._jacobian("alg", "x"),
                    self._jacobian("alg", "z"),
                ],
                _ARGS,
                ["ode_x", "ode_z", "alg_x", "alg_z"],
            )
        if which == "start":
            starts = [
                cs.vertcat(*[cs.SX(self.variables[n].start) for n in names])
                if names
                else cs.SX(0, 1)
                for names in (self.state_names, self.alg_names, self.input_names)
            ]
            return cs.Function("start", [self.p], starts, ["p"], ["x0", "z0", "u0"])
        raise ValueError(
            f"unknown function '{which}'; one of ode, alg, y, signals, energy, jac, dae_jac, start"
        )

    def linearization(self, outputs: Sequence[str]) -> cs.Function:
        """Exact linearisation ``(x, z, u, p) -> (A, B, C, D)`` of the signals ``outputs``.

        ``dx' = A dx + B du``, ``dy = C dx + D du`` with ``y`` the named signals (any of
        :attr:`signal_names`: states, algebraic and solved variables, inputs, declared
        outputs). Where ``nz > 0``, ``z`` is eliminated by the implicit function theorem,
        ``dz = -g_z^{-1} (g_x dx + g_u du)``; ``z`` must then satisfy ``g(x, z, u, p) = 0``.
        Cached per output list; generates C.

        Raises
        ------
        ParameterError
            For a name that is not a signal of the model.
        """
        key = ("linearization", *outputs)
        cache = self.__dict__.setdefault("_functions", {})
        if key not in cache:
            index = {n: i for i, n in enumerate(self.signal_names)}
            for n in outputs:
                if n not in index:
                    close = difflib.get_close_matches(n, self.signal_names, n=3)
                    hint = f"did you mean {close}?" if close else "see model.signal_names"
                    raise ParameterError("outputs", n, f"a signal of model '{self.name}'", hint)
            rows = [index[n] for n in outputs]
            cache[key] = self._linear("linearization", self._signals[rows])
        return cache[key]

    def _jacobian(self, of: str, wrt: str) -> cs.SX:
        """``d of / d wrt`` (``of`` "ode" or "alg", ``wrt`` "x", "z" or "u"), computed once
        per model: linearisations, "dae_jac" and equilibria share it."""
        return self.cached(
            ("jacobian", of, wrt), lambda: cs.jacobian(getattr(self, of), getattr(self, wrt))
        )

    def _linear(self, name: str, h: cs.SX) -> cs.Function:
        """``A, B, C, D`` of ``(ode, h)`` with ``z`` eliminated (implicit function theorem)."""
        jac = {("f", v): self._jacobian("ode", v) for v in ("x", "u")}
        jac.update({("h", v): cs.jacobian(h, sym) for v, sym in (("x", self.x), ("u", self.u))})
        if self.nz:
            # dz/d[x, u] = -g_z^{-1} [g_x, g_u]
            g_xu = cs.jacobian(self.alg, cs.vertcat(self.x, self.u))
            dz = -cs.solve(cs.jacobian(self.alg, self.z), g_xu)
            for e, expr in (("f", self.ode), ("h", h)):
                through_z = cs.mtimes(cs.jacobian(expr, self.z), dz)
                # not +=: the shared Jacobians stay as they are
                jac[e, "x"] = jac[e, "x"] + through_z[:, : self.nx]
                jac[e, "u"] = jac[e, "u"] + through_z[:, self.nx :]
        out = [jac["f", "x"], jac["f", "u"], jac["h", "x"], jac["h", "u"]]
        return cs.Function(name, self._syms, out, _ARGS, ["A", "B", "C", "D"])

    @functools.cached_property
    def bounded_signal_names(self) -> list[str]:
        """Signals with a physical domain (finite ``low`` or ``high``)."""
        return [
            n
            for n in self.signal_names
            if np.isfinite(self.variables[n].low) or np.isfinite(self.variables[n].high)
        ]

    def signals_function(self, names: Sequence[str], n_points: int = 1) -> cs.Function:
        """``signals(x, z, u, p)`` for a subset of :attr:`signal_names`, mapped over
        ``n_points`` columns (cached)."""
        key = ("signals", n_points, *names)
        cache = self.__dict__.setdefault("_functions", {})
        if key not in cache:
            index = {n: i for i, n in enumerate(self.signal_names)}
            rows = [index[n] for n in names]
            expr = self._signals[rows] if rows else cs.SX(0, 1)
            f = cs.Function("signals", self._syms, [expr], _ARGS, ["signals"])
            cache[key] = f.map(n_points) if n_points > 1 else f
            if len(cache) > 64:  # a handful of grids per model; keep the cache bounded
                for old in [k for k in cache if k[0] == "signals"][:32]:
                    del cache[old]
        return cache[key]

    def describe(self) -> str:
        """A one-paragraph summary: sizes and the first variables."""
        return (
            f"model '{self.name}': {self.nx} states, {self.nz} algebraic, "
            f"{len(self.input_names)} inputs, {len(self.param_names)} parameters, "
            f"{len(self.output_names)} outputs"
        )

    def check_finite(self, values: np.ndarray, what: str) -> None:
        """Raise ParameterError if a vector holds NaN or inf (names the first bad entry)."""
        names = {"x": self.state_names, "u": self.input_names, "p": self.param_names}[what]
        for n, v in zip(names, np.ravel(values), strict=True):
            if not math.isfinite(v):
                raise ParameterError(n, v, "a finite number")

    def cached(self, key: object, build):
        """``build()`` memoised on this model by the value of ``key`` (hashable).

        Bounded: at most 256 entries, the least recently used dropped first. The
        simulation methods keep their integrators and step Functions here, so every
        simulator and every ``simulate`` call on the model shares them.
        """
        memo = self.__dict__.setdefault("_memo", {})
        if key in memo:
            memo[key] = value = memo.pop(key)  # most recently used last
            return value
        value = memo[key] = build()
        if len(memo) > 256:
            del memo[next(iter(memo))]
        return value
