"""The stepping simulator: one integration path for closed loops and for ``simulate``.

A :class:`Simulator` holds a model, its settings, the parameters and the current point
``(t, x, z)``. :meth:`Simulator.step` advances it by ``h`` with an input that is either
held constant (a vector, a mapping by input name, unit strings allowed) or given as
signals over the step; :meth:`Simulator.advance` does the same through several output
times at once, which is all :func:`~.simulate.simulate` does. There is no second path:
``step(u, h)`` is ``advance(u, [t + h])``.

How one path serves both a controller's constant ``u`` and a chirp: ``advance`` splits
its interval at the breakpoints of the input signals, and over each piece the inputs
follow an :class:`~.common.InputLaw`:

* **held** - every input is constant over the piece (constants, and the
  piecewise-constant :class:`~sarcomere.dynamics.signals.Step` and
  :class:`~sarcomere.dynamics.signals.Staircase` between breakpoints). The method's
  input argument is ``u`` itself: the CVODES/IDAS integrator takes it as CasADi's
  piecewise-constant control and the fixed-step core as an argument, so a closed loop
  with a new ``u`` every step reuses one integrator;
* **signals** - anything else (ramps, sines, chirps, tables) is integrated exactly as
  the signal's CasADi expression of time, clamped into the piece (a jump at its end
  never leaks into it); the argument is then the piece's bounds.

The method (:data:`~.settings.METHODS`) integrates one piece (a
:class:`~.settings.Segment`); its integrators and step Functions are memoised on the
model (:meth:`Model.cached`) by value: settings, law and relative output grid.

After each piece the simulator checks that the states are finite and that every
bounded signal (``low``/``high`` of its variable: the physical domain) holds at the
output points; a violation is a :class:`~sarcomere.dynamics.errors.SolverError` with the
time of the first violating output point, the signal named and the state there. After
an error the simulator stays at the last point that passed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import casadi as cs
import numpy as np

from ..errors import ParameterError, SolverError
from ..modeling.buffered import BufferedCall
from ..modeling.model import Model
from . import fixed_step, guard, radau, rosenbrock, scipy_methods, sundials  # noqa: F401  (register the methods)
from .common import method_options, require_step
from .inputs import HELD_TYPES, Const, input_ranges, number, signal_of, start_vector, values_at
from .pwm import EffectiveDuty, PulseTrain
from .settings import HELD, METHODS, InputLaw, Pieces, Segment, SolverSettings, segment_w

CHUNK_POINTS = 1000
"""Most output points per method call: long runs are integrated in pieces of this many
points (the method restarts there), so progress can be reported and memory stays flat."""

EXPAND_LIMIT = 60_000
"""Most instructions of a signals Function expanded over its output points (up to some
30 ms to build and 2.5 MB held, once per model, signals and grid size; enough for the 17
bounded signals of the n = 3 chain at 501 points); larger ones stay maps."""


_LAWS = (PulseTrain, EffectiveDuty)
"""What a PWM (:attr:`Model.modulators`) makes of a held duty: also held."""


def _law(signals: list) -> InputLaw:
    held = all(isinstance(sig, HELD_TYPES + _LAWS) for sig in signals)
    return HELD if held else InputLaw(tuple(signals))


class Simulator:
    """Step a model through time; the base of :func:`~.simulate.simulate`.

    Parameters
    ----------
    model : Model
        A flattened model.
    settings : SolverSettings, optional
        Method and tolerances; default CVODES at rtol 1e-6.
    x0, z0, params, t0 : keyword, optional
        The start point, as in :meth:`reset`. Given none of them, the simulator is not
        started: :meth:`step` and :meth:`advance` refuse to run until :meth:`reset`
        chooses the start (``reset()`` for the model's start values, which are not an
        equilibrium: a hanging load starts in free fall).

    Attributes
    ----------
    t : float
        Current time [s].
    x, z : numpy.ndarray
        Current states and algebraic unknowns (copies).
    u : numpy.ndarray
        Current inputs [SI] (the value at ``t`` of what the last step applied).
    p : numpy.ndarray
        Parameters of the current run.
    stats : dict
        Solver counters since the last reset (``n_steps``, ``n_rhs``, ``n_segments``...).

    Examples
    --------
    >>> from sarcomere.dynamics import Simulator, hanging_load, solve_equilibrium
    >>> model = hanging_load(n=1, load_kg=0.05)
    >>> sim = Simulator(model)
    >>> sim.reset(x0=solve_equilibrium(model, {"regulator.p_cmd": 0.0}).x)
    >>> for _ in range(20):
    ...     sim.step({"regulator.p_cmd": "0.1 MPa"}, 0.01)
    >>> round(sim.t, 6), bool(sim.signal("regulator.p_out") > 9e4)
    (0.2, True)
    """

    def __init__(
        self,
        model: Model,
        settings: SolverSettings | None = None,
        *,
        x0: np.ndarray | Mapping[str, float] | None = None,
        z0: np.ndarray | Mapping[str, float] | None = None,
        params: Mapping[str, object] | None = None,
        t0: float | None = None,
    ) -> None:
        self.model = model
        self.settings = settings or SolverSettings()
        self._scheme = guard.SCHEMES.get(self.settings.method)
        self.reset(x0, z0, params, 0.0 if t0 is None else t0)
        self._started = any(v is not None for v in (x0, z0, params, t0))

    # --- state ---------------------------------------------------------------------
    def reset(
        self,
        x0: np.ndarray | Mapping[str, float] | None = None,
        z0: np.ndarray | Mapping[str, float] | None = None,
        params: Mapping[str, object] | None = None,
        t0: float = 0.0,
    ) -> None:
        """Start again at ``t0`` [s] from ``x0`` (vector, or mapping of state names to
        values; default the start values), ``z0`` (guess of the algebraic unknowns) and
        ``params`` (overrides by name, units allowed); inputs return to their start values.
        """
        m = self.model
        if params:
            self.p = m.parameters(params)
        else:  # the defaults: fixed per model
            self.p = m.cached(("default_parameters",), lambda: m.parameters()).copy()
        # the start values at the default parameters (as Model.x0() etc.): fixed per model
        x_start, z_start, u_start = m.cached(("startvalues_at",), lambda: _startvalues_at(m))
        self._x = start_vector(m, "x0", x0, x_start, m.state_names)
        if not np.isfinite(self._x).all():
            m.check_finite(self._x, "x")
        self._z = start_vector(m, "z0", z0, z_start, m.alg_names)
        if not math.isfinite(t0):
            raise ParameterError("t0", t0, "a finite time [s]")
        self._t = float(t0)
        start = m.cached(("start_inputs",), lambda: tuple(Const(float(v)) for v in u_start))
        self._inputs = list(start)
        self._u = u_start.copy()
        self._limit: tuple | None = None
        self._pwm_history = False  # a PWM's duty before the first advance: held as given
        self.stats: dict = {}
        self._started = True

    @property
    def t(self) -> float:
        return self._t

    @property
    def x(self) -> np.ndarray:
        return self._x.copy()

    @property
    def z(self) -> np.ndarray:
        return self._z.copy()

    @property
    def u(self) -> np.ndarray:
        return self._u.copy()

    def signals(self, names: Sequence[str] | None = None) -> dict[str, float]:
        """Named signals [SI] at the current point (default: every named signal)."""
        m = self.model
        names = list(m.signal_names if names is None else names)
        unknown = [n for n in names if n not in m.signal_names]
        if unknown:
            raise ParameterError("signals", unknown[:5], f"signals of model '{m.name}'")
        values = self._signals_at(
            tuple(names), self._x[:, None], self._z[:, None], self._u[:, None]
        )
        return dict(zip(names, values[:, 0].tolist(), strict=True))

    def _signals_at(
        self, names: tuple[str, ...], X: np.ndarray, Z: np.ndarray, U: np.ndarray
    ) -> np.ndarray:
        """Signals ``names`` at the points (columns) of ``X, Z, U``: (names, points)."""
        n, m = X.shape[1], self.model
        key = ("signals_buffer", names, n)  # on the model: shared by every simulator
        call = m.cached(key, lambda: BufferedCall(_points_function(m, names, n)))
        return call(X, Z, U, self.p).reshape(n, len(names)).T

    def signal(self, name: str) -> float:
        """One named signal [SI] at the current point."""
        return self.signals([name])[name]

    def step_function(self) -> cs.Function:
        """The method's CasADi ``step(x, z, u, h, p) -> (xf, zf)`` with ``u`` held: the
        integrator (cvodes, idas) or fixed step the simulator itself uses, callable on MX
        symbols in an optimal-control problem."""
        make = METHODS[self.settings.method].step_function
        if make is None:
            raise ParameterError(
                "solver.method",
                self.settings.method,
                sorted(k for k, v in METHODS.items() if v.step_function is not None),
                "scipy's solvers and the compiled radau are not CasADi Functions",
            )
        return make(self.model, self.settings)

    # --- stepping ------------------------------------------------------------------
    def step(self, u: object, h: float | str) -> None:
        """Advance by ``h`` [s] (a float, or a string with a unit such as "10 ms").

        ``u``: the inputs over the step - a vector (one SI value per input, in
        ``model.input_names`` order), a mapping by input name to an SI float, a string
        with a unit ("0.1 MPa") or a signal (evaluated over the step as an expression of
        time); inputs a mapping leaves out, or ``None``, keep what was applied last.
        Every value is checked against its input's range ``[low, high]``.

        Raises
        ------
        ParameterError
            For a bad input or step size.
        SolverError
            When the method fails or the trajectory leaves the physical domain (the
            time, the state and the cause).
        """
        h = number(h, "s", "h")
        if not (math.isfinite(h) and h > 0):
            raise ParameterError("h", h, "(0, inf) s")
        self.advance(u, [self._t + h])

    def advance(
        self,
        u: object,
        times: Sequence[float] | np.ndarray,
        progress: Callable[[float], None] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance through the increasing ``times`` [s] (the first may equal :attr:`t`),
        ending at the last; ``u`` as in :meth:`step`. ``progress(fraction)`` is called
        after every piece (breakpoint or :data:`CHUNK_POINTS` output points).

        Returns
        -------
        (numpy.ndarray, numpy.ndarray, numpy.ndarray)
            States, algebraic unknowns and inputs at ``times``, one row per time.

        Raises
        ------
        SolverError
            A piece failed; its ``partial`` holds ``(times, X, Z, U)`` up to the failure.
        """
        if not self._started:
            raise ParameterError(
                "x0",
                None,
                "a start: reset(x0=...) (e.g. an equilibrium's x), or reset() for the "
                "model's start values, before step or advance",
                "the simulator was never started",
            )
        m, t_start = self.model, self._t
        times = np.asarray(times, dtype=float).reshape(-1)
        if not len(times) or not np.isfinite(times).all() or times[0] < t_start:
            raise ParameterError("times", times[:3], f"finite times from t = {t_start:g} s on")
        if times[-1] <= t_start:
            raise ParameterError("times", times[-1], f"an end after t = {t_start:g} s")
        if (np.diff(times) <= 0).any():
            raise ParameterError("times", times[:3], "strictly increasing times [s]")
        given = self._input_signals(u)
        signals = self._modulated(given)
        t_end = float(times[-1])
        bps = sorted(
            {
                float(b)
                for sig in signals
                if hasattr(sig, "breakpoints")
                for b in sig.breakpoints(t_start, t_end)
            }
            - {t_start, t_end}
        )
        # the inputs as given at t_start, the times and the breakpoints, in one vectorised call
        V = self._check_range(given, np.concatenate([[t_start], times, bps]))
        if self._scheme is not None:
            self._guard(signals, times, bps)
        nt = len(times)
        X = np.empty((nt, m.nx))
        Z = np.empty((nt, m.nz))
        U = np.empty((nt, len(signals)))
        first = 0
        if times[0] == t_start:
            X[0], Z[0], U[0] = self._x, self._z, V[0]
            first = 1
        edges = [t_start, *bps, t_end]
        span = t_end - t_start
        law = _law(signals)
        held = law is HELD
        # held: the inputs at each edge (for the rows at b) and inside each piece (what is
        # integrated: a PWM edge is a breakpoint only to rounding, the middle is not)
        W = V[[0, *range(nt + 1, nt + 1 + len(bps)), nt]] if held else None  # at the edges
        if held and given is not signals:
            mid = np.array(edges)
            Wi = values_at(signals, 0.5 * (mid[:-1] + mid[1:]))
        else:
            Wi = W
        plan = []  # per piece: w, times, first row, rows kept, ends at b held (U from b on)
        rows = (first + np.searchsorted(times[first:], edges, side="right")).tolist()
        for i, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
            lo, hi = rows[i], rows[i + 1]
            if hi > lo and times[hi - 1] == b:
                seg_times = times[lo:hi]
            else:
                seg_times = np.append(times[lo:hi], b)
            w = Wi[i] if held else segment_w(a, b)
            for k in range(0, len(seg_times), CHUNK_POINTS):
                piece = seg_times[k : k + CHUNK_POINTS]
                n_out = max(min(len(piece), hi - lo - k), 0)  # b may be a breakpoint only
                at_b = held and n_out == len(piece) and piece[-1] == b
                plan.append((w, piece, lo + k, n_out, W[i + 1] if at_b else None))
        method = METHODS[self.settings.method]
        if method.pieces is not None and progress is None:
            self._pieces(method, law, signals, plan, X, Z, U, first, times)
        else:
            done = first  # rows filled: what a failure keeps (SolverError.partial)
            for w, piece, row, n_out, u_b in plan:
                try:
                    Xp, Zp, Up = self._piece(law, w, signals, piece)
                except SolverError as exc:
                    exc.partial = (times[:done], X[:done], Z[:done], U[:done])
                    raise
                rows = slice(row, row + n_out)
                X[rows], Z[rows], U[rows] = Xp[:n_out], Zp[:n_out], Up[:n_out]
                if u_b is not None:
                    U[rows.stop - 1] = u_b  # at b itself the input's value from b on
                done = rows.stop
                if progress is not None:
                    progress((self._t - t_start) / span if span > 0 else 1.0)
        self._inputs = given
        self._u = V[nt].copy()  # at t_end
        if given is not signals:  # the rows show the inputs as given (the duty)
            U = values_at(given, times) if len(given) else U
        return X, Z, U

    def input_law(self, u: object = None) -> InputLaw:
        """The input law :meth:`advance` with ``u`` integrates under from here."""
        history = self._pwm_history
        try:
            return _law(self._modulated(self._input_signals(u)))
        finally:  # asking changes nothing
            self._pwm_history = history

    def _modulated(self, given: list) -> list:
        """``given`` with each PWM-modulated input (:attr:`Model.modulators`) replaced by
        its law (:meth:`~.pwm.PWM.law`); ``given`` itself without modulators."""
        m = self.model
        if not m.modulators:
            return given
        out = list(given)
        for name, pwm in m.modulators.items():
            i = m.input_names.index(name)
            if not all(isinstance(sig, HELD_TYPES) for sig in given):
                raise ParameterError(
                    name,
                    [type(sig).__name__ for sig in given],
                    "piecewise-constant inputs (constants, steps, staircases) with a PWM",
                    "the PWM samples the duty as it comes, and its command is integrated "
                    "held between its edges",
                )
            before = self._inputs[i] if self._pwm_history else given[i]
            out[i] = pwm.law(given[i], before, self._t)
        self._pwm_history = True
        return out

    def _piece(
        self, law: InputLaw, w: np.ndarray, signals: list, times: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Integrate one piece with the method, check it, move to its end."""
        m = self.model
        seg = Segment(
            m,
            self.settings,
            self.p,
            law,
            w,
            self._t,
            self._x,
            self._z,
            times,
            self.stats,
        )
        X, Z = METHODS[self.settings.method].run(seg)
        U = np.repeat(w[None, :], len(times), axis=0) if law is HELD else values_at(signals, times)
        bad = ~(np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(Z), axis=1))
        if bad.any():
            i = int(np.argmax(bad))
            raise seg.fail(
                "the state became non-finite", float(times[i]), X[i - 1] if i else seg.x0
            )
        self._check_domain(seg, X, Z, U)
        self._t, self._x, self._z = float(times[-1]), X[-1].copy(), Z[-1].copy()
        return X, Z, U

    def _pieces(self, method, law, signals, plan, X, Z, U, first, times) -> None:
        """Every piece of ``plan`` in one call of the method (:attr:`Method.pieces`), with
        the same numbers, checks and failures as :meth:`_piece` piece by piece."""
        m = self.model
        lens = [len(q[1]) for q in plan]
        ends = np.cumsum(lens, dtype=np.int32)
        # one piece: its times as they are, unless a strided view (t_out[::4], a CSV's
        # column) that C would read as contiguous (it read every row, not every 4th)
        all_times = np.concatenate([q[1] for q in plan]) if len(plan) > 1 else plan[0][1]
        all_times = np.ascontiguousarray(all_times)
        Wm = np.ascontiguousarray([q[0] for q in plan], dtype=float)
        run = Pieces(m, self.settings, self.p, law, Wm, self._t, self._x, all_times, ends,
                     self.stats)  # fmt: skip
        Xall, fail = method.pieces(run)
        Uall = np.repeat(Wm, lens, axis=0) if law is HELD else values_at(signals, all_times)
        for k, q in enumerate(plan):  # held: at b itself the input's value from b on
            if q[4] is not None:
                Uall[ends[k] - 1] = q[4]
        n_done = len(plan) if fail is None else fail.piece
        rows = zip(plan, lens, ends[:n_done], strict=False)
        keep = [np.arange(e - n, e - n + q[3]) for q, n, e in rows]
        keep = np.concatenate(keep) if keep else np.zeros(0, dtype=int)  # output times only
        stop = first + len(keep)
        X[first:stop], U[first:stop], Z[first:stop] = Xall[keep], Uall[keep], 0.0
        if n_done:
            end = int(ends[n_done - 1]) - 1
            self._t, self._x, self._z = float(all_times[end]), Xall[end].copy(), np.zeros(m.nz)
        if fail is None:
            return
        w, piece = plan[fail.piece][:2]
        seg = Segment(m, self.settings, self.p, law, w, self._t, self._x, self._z, piece,
                      self.stats)  # fmt: skip
        i = fail.row - (int(ends[fail.piece]) - len(piece))  # the row in the piece
        if fail.cause is not None:
            exc = seg.fail(fail.cause, fail.t, fail.x)
        elif fail.signal < 0:
            x_before = Xall[fail.row - 1] if i else seg.x0
            exc = seg.fail("the state became non-finite", float(piece[i]), x_before)
        else:
            names = m.cached(("domain",), lambda: _domain(m))[0]
            t = float(piece[i])
            exc = _domain_error(seg, names[fail.signal], fail.value, t, Xall[fail.row])
        exc.partial = (times[:stop], X[:stop], Z[:stop], U[:stop])
        raise exc

    # --- checks --------------------------------------------------------------------
    def _check_domain(self, seg: Segment, X: np.ndarray, Z: np.ndarray, U: np.ndarray) -> None:
        """Refuse the first output point where a bounded signal leaves ``[low, high]``."""
        m = self.model
        names, low, high = m.cached(("domain",), lambda: _domain(m))
        if not names:
            return
        S = self._signals_at(names, X.T, Z.T, U.T)
        out = (S < low) | (S > high) | ~np.isfinite(S)
        if not out.any():
            return
        col = int(np.argmax(out.any(axis=0)))
        row = int(np.argmax(out[:, col]))
        raise _domain_error(seg, names[row], S[row, col], float(seg.times[col]), X[col])

    def _check_range(self, signals: list, times: np.ndarray) -> np.ndarray:
        """The inputs at ``times`` (one row per time); refuse one outside its variable's
        range."""
        m = self.model
        V = values_at(signals, times)
        low, high = m.cached(("input_ranges",), lambda: input_ranges(m))
        if ((V >= low) & (V <= high)).all():
            return V
        for k, name in enumerate(m.input_names):
            var, values = m.variables[name], V[:, k]
            bad = np.flatnonzero(~((values >= var.low) & (values <= var.high)))
            if bad.size:
                value = f"{values[bad[0]]:g} {var.unit} at t = {times[bad[0]]:g} s"
                raise var.refuse(name, value, var.description)
        return V

    def _guard(self, signals: list, times: np.ndarray, bps: list[float]) -> None:
        """The explicit-step stability guard (:mod:`.guard`); the limit is estimated at the
        first advance after a reset and kept."""
        action = guard.on_unstable(method_options(self.settings, {"on_unstable": "warn"}))
        if action == "ignore":
            return
        h_used = fixed_step.max_substep(
            np.concatenate([[self._t], times, bps]), require_step(self.settings)
        )
        if self._limit is None:
            t_after = bps[0] if bps else float(times[-1])
            self._limit = guard.stability_limit(
                self.model,
                self._scheme,
                self._x,
                values_at(signals, self._t),
                t_after,
                values_at(signals, t_after),
                self.p,
            )
            self.stats["stability_limit_s"] = self._limit[0]
        guard.check_step(self._scheme, h_used, action, self._limit)

    def _input_signals(self, u: object) -> list:
        """One signal per input from ``u`` (see :meth:`step`)."""
        m = self.model
        if u is None:
            return list(self._inputs)
        if isinstance(u, Mapping):
            unknown = set(u) - set(m.input_names)
            if unknown:
                raise ParameterError(
                    "inputs", sorted(unknown), f"inputs of model '{m.name}': {m.input_names}"
                )
            out = list(self._inputs)
            for name, spec in u.items():
                out[m.input_names.index(name)] = signal_of(m, name, spec)
            return out
        vec = np.asarray(u, dtype=float).reshape(-1)
        if len(vec) != len(m.input_names):
            raise ParameterError(
                "u", f"{len(vec)} values", f"{len(m.input_names)} values for {m.input_names}"
            )
        for name, v in zip(m.input_names, vec, strict=True):
            if not math.isfinite(v):
                raise ParameterError(name, float(v), "a finite number")
        return [Const(float(v)) for v in vec]


def _startvalues_at(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x0``, ``z0`` and ``u0`` at the default parameters, in one call."""
    start = model.function("start").call([model.parameters()])
    return tuple(np.array(v, dtype=float).reshape(-1) for v in start)


def _domain_error(seg: Segment, name: str, value: float, t: float, x: np.ndarray) -> SolverError:
    """The failure of bounded signal ``name`` at ``value`` outside its range at ``t``."""
    var = seg.model.variables[name]
    return seg.fail(
        f"left the physical domain: {name} = {value:.4g} {var.unit} is outside "
        f"{var.range_str} ({var.description})",
        t,
        x,
    )


def _domain(model: Model) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """The bounded signals and their ``low`` and ``high`` as (signals, 1) columns."""
    names = tuple(model.bounded_signal_names)
    low = np.array([model.variables[k].low for k in names])[:, None]
    high = np.array([model.variables[k].high for k in names])[:, None]
    return names, low, high


def _points_function(model: Model, names: tuple[str, ...], n: int) -> cs.Function:
    """``signals(X, Z, U, p)`` at ``n`` points (columns of ``X, Z, U``), ``p`` shared.
    Expanded into one SX Function (no call per point: half the time of a map, same
    operations) while it stays under :data:`EXPAND_LIMIT` instructions."""
    f = model.signals_function(list(names))
    mapped = f.map("signals", "serial", n, [3], [])
    return mapped.expand() if f.n_instructions() * n <= EXPAND_LIMIT else mapped
