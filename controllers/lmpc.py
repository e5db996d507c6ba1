"""Linear MPC: a condensed QP in velocity form on the exact, ZOH-discretised linearisation.

The prediction uses increments: the state ``xi = [dx_k; e_k]`` with ``dx_k = x_k - x_{k-1}``
(the measured states) and ``e_k = y_k - r`` (the tracked output minus its reference), the
decision variables are the input moves ``du_k``::

    dx_{k+1} = Ad dx_k + Bd du_k
    e_{k+1}  = e_k + C Ad dx_k + C Bd du_k

A constant disturbance or a model error shifts ``x`` and ``u`` but not the increments, so
the loop has integral action (offset-free) without an observer. The cost is
``sum_k q (y_k - r_k)^2 + r_du du_k^2`` over the horizon (``r_k`` the reference at node
``k``: the preview set by :meth:`~.receding.RecedingHorizon.set_preview` when the reference
is known ahead, else ``r(t)`` held; ``e_k - (r_k - r(t))`` in the increments); input
bounds and rate limits are hard (``du = 0`` always satisfies them, so the QP is always
feasible); lower bounds on other signals (e.g. thread tension) are soft, with one slack
per signal (linear and quadratic penalty). The QP is condensed (only the moves and slacks
are unknowns) and solved by ``casadi.conic`` (qpOASES or DAQP), built once; each sample
passes flat numeric vectors.

The model is re-linearised at the measured point ``(x, u)`` when the tracked output has
moved more than ``relinearize_m`` (default 2 mm, about a quarter of the 8.8 mm 3-APS stroke at
20 g) from where it was last linearised, or when a parameter set at run time
(:meth:`~.receding.RecedingHorizon.set_parameters`, e.g. the EKF's load estimate) moved more
than ``relinearize_rel`` (default 5 %) of its value there.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import casadi as cs
import control as ct
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.labels import to_label
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .qp import qp_solver, zoh
from .receding import TENSION, RecedingHorizon, check_horizon, mpc_settings, with_estimator
from .registry import positive, register_controller


@dataclass(frozen=True)
class LMPCSettings:
    """Settings of :class:`LinearMPC` (SI).

    Attributes
    ----------
    horizon : int
        Prediction and control horizon [samples].
    weight_y : float
        Weight of the squared tracking error [1/m^2].
    weight_du : float
        Weight of the squared input move per sample [1/Pa^2]. The default (a 1.8 kPa
        move costs as much as 1 mm of error; chosen by the tuning study
        :mod:`sarcomere.scenarios.studies.mpc_tuning`) keeps the loop stable when the
        plant carries 50 g more than the linearisation (at 1e-8 it cycles between 0.14
        and 0.3 MPa in the control-length scene).
    u_min, u_max : float
        Regulator command bounds [Pa gauge].
    rate_max : float
        Largest input rate [Pa/s]; a move per sample is at most ``rate_max * dt``.
    soft_min : tuple of (str, float)
        Soft lower bounds on signals (e.g. ``(("myofibril.actin1.T", 0.01),)``, SI).
    weight_slack : float
        Linear and quadratic penalty on a soft-bound violation [per unit of the signal].
    relinearize_m : float
        Re-linearise when the tracked output moved this far from the last point [m].
    relinearize_rel : float
        Re-linearise when a parameter (one set at run time, e.g. an estimated load) moved
        this fraction of its value at the last point [-] (default 5 %: 3.5 g of 70 g).
    output : str
        The tracked signal.
    qp_solver : str
        "daqp" (default) or "qpoases".
    """

    horizon: int = 20
    weight_y: float = 1.0e6
    weight_du: float = 3.0e-7
    u_min: float = 0.0
    u_max: float = 1.0e5
    rate_max: float = 2.0e6
    soft_min: tuple = ()
    weight_slack: float = 1.0e4
    relinearize_m: float = 2.0e-3
    relinearize_rel: float = 0.05
    output: str = "myofibril.length"
    qp_solver: str = "daqp"

    def __post_init__(self) -> None:
        check_horizon("lmpc.horizon", self.horizon)
        positive("lmpc", "weight_y", self.weight_y)
        positive("lmpc", "weight_du", self.weight_du, allow_zero=True)
        positive("lmpc", "rate_max", self.rate_max)
        positive("lmpc", "weight_slack", self.weight_slack)
        positive("lmpc", "relinearize_m", self.relinearize_m)
        positive("lmpc", "relinearize_rel", self.relinearize_rel)
        if not self.u_min < self.u_max:
            raise ParameterError("lmpc.u_max", self.u_max, f"> u_min = {self.u_min:g} Pa")


@dataclass
class VelocityQP:
    """The condensed QP of one linearisation (see the module docstring).

    Parameters
    ----------
    Ad, Bd : numpy.ndarray
        Discrete-time state and input matrices (nx x nx, nx x nu).
    C : numpy.ndarray
        Tracked outputs (ny x nx).
    Cs : numpy.ndarray
        Softly bounded signals (ns x nx), may have zero rows.
    horizon : int
    weight_y, weight_du, weight_slack : float
    u_scale : numpy.ndarray
        Scale of each input [SI]: the QP's unknowns are ``du / u_scale``.
    solver : casadi.Function
        A conic solver for the sparsities :meth:`sparsities` gives.
    """

    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    Cs: np.ndarray
    horizon: int
    weight_y: float
    weight_du: float
    weight_slack: float
    u_scale: np.ndarray
    solver: cs.Function
    H: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        nx, nu = self.Bd.shape
        ny, ns, N = self.C.shape[0], self.Cs.shape[0], self.horizon
        Phi = np.block([[self.Ad, np.zeros((nx, ny))], [self.C @ self.Ad, np.eye(ny)]])
        Gam = np.vstack([self.Bd, self.C @ self.Bd]) * self.u_scale[None, :]
        n = nx + ny
        Sx = np.zeros((N * n, n))
        Su = np.zeros((N * n, N * nu))
        P = np.eye(n)
        for k in range(N):
            P = Phi @ P
            Sx[k * n : (k + 1) * n] = P
        for j in range(N):
            blk = Gam
            for k in range(j, N):
                Su[k * n : (k + 1) * n, j * nu : (j + 1) * nu] = blk
                blk = Phi @ blk
        # the tracking errors e_1..e_N: the last ny rows of every block of n
        Se_x = Sx.reshape(N, n, n)[:, nx:].reshape(N * ny, n)
        Se_u = Su.reshape(N, n, N * nu)[:, nx:].reshape(N * ny, N * nu)
        self.nu, self.ns = nu, ns
        nv = N * nu + ns
        H = np.zeros((nv, nv))
        H[: N * nu, : N * nu] = 2 * (
            self.weight_y * Se_u.T @ Se_u + self.weight_du * np.diag(np.tile(self.u_scale**2, N))
        )
        H[N * nu :, N * nu :] = 2 * self.weight_slack * np.eye(ns)
        self.H = H
        self._G = 2 * self.weight_y * Se_u.T @ Se_x  # gradient = G xi0
        self._Gr = 2 * self.weight_y * Se_u.T  # minus this times the reference ahead
        # inputs: u_k = u_prev + sum_{j<=k} du_j
        T = np.kron(np.tril(np.ones((N, N))), np.diag(self.u_scale))
        # soft signals at k = 1..N: s_0 + Cs (x_k - x_0), x_k - x_0 = sum_{i<=k} dx_i
        # (cumulative sums of the dx rows: no (N nx) x (N n) summation matrix)
        cum_x = np.cumsum(Sx.reshape(N, n, n)[:, :nx], axis=0)
        cum_u = np.cumsum(Su.reshape(N, n, N * nu)[:, :nx], axis=0)
        self._Ssx = np.einsum("sx,kxj->ksj", self.Cs, cum_x).reshape(N * ns, n)
        Ssu = np.einsum("sx,kxj->ksj", self.Cs, cum_u).reshape(N * ns, N * nu)
        A = np.zeros((N * nu + N * ns, nv))
        A[: N * nu, : N * nu] = T
        A[N * nu :, : N * nu] = Ssu
        A[N * nu :, N * nu :] = np.kron(np.ones((N, 1)), np.eye(ns))
        self.A = A

    def sparsities(self) -> tuple[cs.Sparsity, cs.Sparsity]:
        """Dense sparsities of the Hessian and the constraint matrix."""
        return cs.Sparsity.dense(*self.H.shape), cs.Sparsity.dense(*self.A.shape)

    def solve(
        self,
        xi0: np.ndarray,
        u_prev: np.ndarray,
        u_lo: np.ndarray,
        u_hi: np.ndarray,
        du_max: np.ndarray,
        soft_gap: np.ndarray,
        ahead: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, bool]:
        """The moves ``du`` (horizon x nu, SI) and whether the solver succeeded.

        ``soft_gap``: each soft bound minus the signal's present value (ns). ``ahead``: the
        reference at nodes ``1..horizon`` minus the one in ``xi0``'s error [SI] (horizon x
        ny; default zero: the reference held over the horizon).
        """
        N, nu, ns = self.horizon, self.nu, self.ns
        grad = self._G @ xi0
        if ahead is not None:
            grad = grad - self._Gr @ np.ravel(ahead)
        g = np.concatenate([grad, np.full(ns, self.weight_slack)])
        lba = np.concatenate([np.tile(u_lo - u_prev, N), np.tile(soft_gap, N) - self._Ssx @ xi0])
        uba = np.concatenate([np.tile(u_hi - u_prev, N), np.full(N * ns, np.inf)])
        lbx = np.concatenate([np.tile(-du_max / self.u_scale, N), np.zeros(ns)])
        ubx = np.concatenate([np.tile(du_max / self.u_scale, N), np.full(ns, np.inf)])
        sol = self.solver(h=self.H, g=g, a=self.A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        v = np.array(sol["x"]).ravel()
        ok = bool(self.solver.stats()["success"]) and bool(np.all(np.isfinite(v)))
        return (v[: N * nu].reshape(N, nu) * self.u_scale if ok else None), ok


class LinearMPC(RecedingHorizon):
    """Linear MPC of the tracked output (see the module docstring) by the regulator command.

    Reads every state of ``model``, the tracked output and the softly bounded signals by
    name (state feedback: the plant's signals of the same names, or an estimator's), and
    the reference of the tracked output.

    Parameters
    ----------
    model : Model
        The prediction model (its states must be signals the loop can measure).
    x_op, u_op : numpy.ndarray
        The first linearisation point (an equilibrium).
    dt : float
        Sample time [s].
    settings : LMPCSettings, optional
    params : mapping of str to float, optional
        Parameter overrides of ``model`` by name (SI), e.g. the plant's load.

    Examples
    --------
    >>> from sarcomere.dynamics import hanging_load, solve_equilibrium
    >>> m = hanging_load(1, load_kg=0.02)
    >>> eq = solve_equilibrium(m, {"regulator.p_cmd": 5e4})
    >>> mpc = LinearMPC(m, eq.x, eq.u, 0.01)
    >>> y = {n: eq[n] for n in mpc.outputs}
    >>> u = mpc.checked(0.0, y, {"myofibril.length": eq["myofibril.length"]})
    >>> round(u["regulator.p_cmd"])
    50000
    """

    slug = "lmpc"

    def __init__(
        self,
        model: Model,
        x_op: np.ndarray,
        u_op: np.ndarray,
        dt: float,
        settings: LMPCSettings | None = None,
        params: Mapping[str, float] | None = None,
    ) -> None:
        s = settings or LMPCSettings()
        names = model.input_names
        reads = list(dict.fromkeys([*model.state_names, s.output, *(n for n, _ in s.soft_min)]))
        super().__init__(model, dt, s, reads, params)
        self._soft = [name for name, _ in s.soft_min]
        self._soft_min = np.array([float(v) for _, v in s.soft_min])
        self._lin = model.linearization([s.output, *self._soft])
        self._du_max = np.full(len(names), s.rate_max * self.dt)
        self._u_scale = self._u_hi - self._u_lo
        n_v = s.horizon * len(names) + len(self._soft)
        n_a = s.horizon * (len(names) + len(self._soft))
        self._solver = qp_solver(
            s.qp_solver, cs.Sparsity.dense(n_v, n_v), cs.Sparsity.dense(n_a, n_v)
        )
        self.relinearizations = 0
        self._qp = self._linearize(np.asarray(x_op, float), np.asarray(u_op, float))
        self.reset(u_op)

    def _linearize(self, x: np.ndarray, u: np.ndarray) -> VelocityQP:
        A, B, C, _ = (np.array(M) for M in self._lin(x, np.zeros(0), u, self._p))
        Ad, Bd = zoh(A, B, self.dt)
        s = self.settings
        qp = VelocityQP(
            Ad, Bd, C[:1], C[1:], s.horizon, s.weight_y, s.weight_du, s.weight_slack,
            self._u_scale, self._solver,
        )  # fmt: skip
        out = self.model.signals_function([s.output])(x, np.zeros(0), u, self._p)
        self._y_lin, self._p_lin = float(out), self._p.copy()
        self._lin_point = (x.copy(), u.copy(), self._y_lin)
        self.relinearizations += 1
        return qp

    def reset(self, u0: Mapping[str, float] | np.ndarray) -> None:
        super().reset(u0)
        self._x_prev: np.ndarray | None = None

    def as_iosystem(self) -> ct.NonlinearIOSystem:
        """The law as a discrete python-control I/O system, in deviations from the point of
        the last linearisation: inputs ``reference`` and the states and the output (labels
        as :func:`~.linearize.linearize`: link a plant linearised there with outputs
        ``state_names + [output]``), output the input; states the last states and input.
        A linear plant needs no re-linearisation, reference clip or soft bound: none here.
        """
        m, n = self.model, self.model.nx
        x_op, u_op, _ = self._lin_point
        off = np.full(len(self._soft), -np.inf)  # soft bounds inactive

        def law(xs, inp):
            x_prev, u_prev, x = x_op + xs[:n], u_op + xs[n:], x_op + inp[1 : 1 + n]
            xi0 = np.concatenate([x - x_prev, [inp[1 + n] - inp[0]]])
            du, ok = self._qp.solve(xi0, u_prev, self._u_lo, self._u_hi, self._du_max, off)
            return np.clip(u_prev + du[0] if ok else u_prev, self._u_lo, self._u_hi)

        return ct.nlsys(
            lambda t, xs, inp, params: np.concatenate([inp[1 : 1 + n], law(xs, inp) - u_op]),
            lambda t, xs, inp, params: law(xs, inp) - u_op,
            inputs=[
                "reference",
                *[to_label(v) for v in m.state_names],
                to_label(self.settings.output),
            ],
            outputs=[to_label(v) for v in self.inputs],
            states=[*[f"last_{to_label(v)}" for v in m.state_names], "last_input"],
            dt=self.dt,
            name="lmpc",
        )

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        s = self.settings
        x = np.array([y[n] for n in self.model.state_names], dtype=float)
        out = float(y[s.output])
        ref = self.clip(r)
        moved = np.abs(self._p - self._p_lin) > s.relinearize_rel * np.abs(self._p_lin)
        if abs(out - self._y_lin) > s.relinearize_m or np.any(moved):
            self._qp = self._linearize(x, self._u)
        dx = np.zeros_like(x) if self._x_prev is None else x - self._x_prev
        self._x_prev = x
        soft_now = np.array([y[n] for n in self._soft], dtype=float) if self._soft else None
        gap = self._soft_min - soft_now if self._soft else np.zeros(0)
        xi0 = np.concatenate([dx, [out - ref]])
        ahead = self.nodes(ref) - ref  # the reference ahead, relative to r(t)
        du, ok = self._qp.solve(xi0, self._u, self._u_lo, self._u_hi, self._du_max, gap, ahead)
        return self.apply(self._u + np.cumsum(du, axis=0) if ok else None)


def make_lmpc(model: Model, op: Equilibrium, dt: float, settings: dict) -> Controller:
    """Registry factory of ``lmpc``: linearised on the plant ``model`` itself at ``op``.

    Common keys: ``output``, ``input`` (the model's one input), ``u_min``, ``u_max``;
    ``tension_min`` (if set) becomes a soft lower bound on every thread tension. Own keys:
    the other :class:`LMPCSettings` fields, ``estimator`` ("none", or "ekf": run on an
    EKF fed the ``measured`` signals, see :mod:`.estimated`) and ``ekf`` (its settings).
    """
    own, est, ekf_settings = mpc_settings("lmpc", model, settings, LMPCSettings, {})
    tmin = settings.get("tension_min")
    soft = own.pop("soft_min")
    if tmin is not None:
        soft = (*soft, *((n, float(tmin)) for n in model.signal_names if TENSION.fullmatch(n)))
    s = LMPCSettings(
        **own,
        soft_min=tuple(soft),
        output=settings["output"],
        u_min=float(settings["u_min"]),
        u_max=float(settings["u_max"]),
    )
    given = dict(zip(model.param_names, np.asarray(op.p, float), strict=True))
    ctl = LinearMPC(model, op.x, op.u, dt, s, given)
    return with_estimator("lmpc", ctl, model, op, dt, settings, est, ekf_settings)


register_controller("lmpc", make_lmpc)
