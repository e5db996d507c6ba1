"""Nonlinear MPC on the model's own equations: a real-time iteration on Radau IIA
collocation (:mod:`.rti`).

The prediction model should be built for optimisers
(``hanging_load(..., flow_law="smooth", saturate=False)``): the smooth flow law keeps every
derivative continuous, and the input's range is a bound of the problem, not a clamp.

Discretisation: one Radau IIA collocation element of ``degree`` points (default 3, order 5,
L-stable) per sample interval, states scaled by their magnitude over the operating range.
Cost ``sum_k weight_y (y_k - r_k)^2 + weight_du (u_k - u_{k-1})^2`` with ``r_k`` the
reference at node ``k`` (``t + k dt``): the values handed over by
:meth:`~.receding.RecedingHorizon.set_preview` when the reference is known ahead, else
``r(t)`` at every node; plus ``terminal_weight (y_N - r_N)^2``; constraints: the input
within ``[u_min, u_max]``, its rate within ``rate_max``, and the lower bounds ``soft_min``
(by default every thread tension ``>= 0``) at every node from ``k = 1`` on: soft (one
slack per node, exact L1 plus quadratic penalty: the hard solution wherever that is
feasible) or hard (penalty ``inf``).

The solution is a real-time iteration (one Gauss-Newton SQP step per sample) on the
multiple-shooting form: each interval is integrated by the same Radau IIA equations solved
by Newton, its sensitivities come from the implicit function theorem, the QP is condensed
onto the input moves and solved by ``casadi.conic`` (DAQP by default), all in pure CasADi
Functions (preparation, feedback, update; :meth:`NonlinearMPC.law_function` composes them
into one law), optionally generated to C and compiled (``compiled``). The converged NLP
(IPOPT, fatrop) it is compared with lives in the speed study
(:mod:`sarcomere.scenarios.studies.mpc_nlp`).

Parameters of the prediction (the load, the geometry, the regulator) are run-time inputs of
the law, not constants: :meth:`NonlinearMPC.set_parameters` changes them between samples,
and on an EKF (:class:`~.estimated.OnEstimate`) the estimated load is fed every sample, so
the prediction carries the load the plant has (offset-free by the disturbance model), and
with ``backoff`` the EKF's standard deviation of each bounded signal raises its bound. On
the states themselves (no EKF) the NMPC runs its own Kalman filter of one disturbance
(``disturbance``: "load", "input" or "output"; the LMPC's filter,
:class:`~.disturbance.StateDisturbanceFilter`) and feeds its estimate the same way; the
law Function is the same, only its ``p`` changes.

Integral action (``integral_gain``, default 5 1/s; :func:`make_nmpc` makes it 0 when an
EKF or the own filter feeds an estimate): the reference the optimiser sees is moved by
the integrated tracking error, so a load the prediction does not know (the +50 g
disturbance) leaves no steady offset, slowly.

A failed sample (the QP's answer infeasible or not finite) falls back to the previous plan
shifted by one sample and is counted in ``stats.fallbacks``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import casadi as cs
import numpy as np

from sarcomere.dynamics.equilibrium import Equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.modeling.model import Model

from .base import Controller
from .disturbance import DISTURBANCES, StateDisturbanceFilter, check_disturbance
from .ekf import DEFAULT_STD, OFFSETS, estimated_parameters
from .qp import QP_SOLVERS
from .receding import (
    TENSIONS,
    RecedingHorizon,
    check_mpc_settings,
    ekf_disturbance,
    mpc_settings,
    soft_bounds,
    with_estimator,
)
from .registry import count, positive, register_controller
from .rti import LINEAR_SOLVERS, Prediction, RealTimeIteration


@dataclass(frozen=True)
class NMPCSettings:
    """Settings of :class:`NonlinearMPC` (SI).

    Attributes
    ----------
    horizon : int
        Prediction horizon [samples].
    weight_y : float
        Weight of the squared tracking error [1/m^2].
    weight_du : float
        Weight of the squared input move per sample [1/Pa^2].
    u_min, u_max : float
        Regulator command bounds [Pa gauge] (default 0 to 0.1 MPa).
    rate_max : float
        Largest input rate [Pa/s].
    soft_min : tuple
        Lower bounds on signals, at every node from ``k = 1`` on: entries
        ``(signal, bound)`` or ``(signal, bound, penalty)`` [SI; penalty per unit of the
        signal, ``inf`` for a hard bound; default ``soft_penalty``]; ``signal`` may be a
        pattern (``*``: :data:`~.receding.TENSIONS`, every thread tension). Default:
        every thread tension >= 0, soft. The soft bounds share one slack per node (one
        penalty for all of them).
    soft_penalty : float
        The penalty of a soft bound's slack ``s >= 0`` [per unit of the signal], both
        linear and quadratic: ``soft_penalty (s + s^2)``. Exact (L1): above the bounds'
        multipliers (up to about 2e3 1/N in the venting test at 0.2 N,
        ``tests/controllers/test_nmpc.py``), so the soft solution is the hard one whenever
        the hard one is feasible.
    backoff : float
        Raise every bound by ``backoff`` times the standard deviation of its signal's
        estimate [-], fed at run time (:attr:`~.rti.Prediction.backoffs`) by the EKF the
        NMPC runs on (:class:`~.estimated.OnEstimate`); 0 (default): none, and no such
        run-time input.
    degree : int
        Radau IIA collocation points per interval (1..5).
    qp_solver : str
        QP solver of the real-time iteration: "daqp" (default: its generated C compiles
        against the static DAQP library and headers the casadi wheel ships, so the law
        exports with libc as its only dependency), "qrqp" (self-contained C, but it cycles
        on the degenerate active sets of a start at an input bound: a fallback, hundreds
        of iterations), "qpoases" or "hpipm" (not code-generable here).
    output : str
        The tracked signal.
    integral_gain : float
        Integral action [1/s]: the reference given to the optimiser is moved by
        ``integral_gain * integral of (r - y) dt`` (not while the input is at a bound or
        moves at the rate limit: anti-windup), so
        a load or model error the prediction does not know leaves no steady offset; 0
        turns it off (:func:`make_nmpc` defaults to 0 where an EKF or the own filter,
        ``disturbance``, feeds an estimate: the prediction then knows the load).
    terminal_weight : float
        Extra weight of the squared tracking error at the last node [1/m^2], added to
        ``weight_y`` there (default 0: the 0.2 s horizon outlasts the regulator lag and
        the chain's settling, so the last node needs no extra pull; raise it for short
        horizons).
    compiled : bool
        Run the RTI as generated C, compiled with gcc and cached on disk
        (:mod:`.rti_compiled`): the linearisation, the condensing, the feedback and the
        update, with the lifted linear solves as the kept sparse LU of
        :mod:`~sarcomere.dynamics.simulation.sparse_lu` (``linear_solver`` "auto"; only the
        small per-interval Functions are generated once, the horizon's loops call them).
        Default false (BENCHMARKS.md, section 5: measured compile time against the time
        saved).
    linear_solver : str
        Linear solver of the lifted Radau equations (:mod:`.rti_lift`): "lapacklu", "qr"
        (CasADi's sparse QR; both solve every sensitivity in the preparation),
        "sparse_lu" (:mod:`~sarcomere.dynamics.simulation.sparse_lu`, the factors as SX
        expressions with the Jacobians,
        kept, each use solving only the right-hand sides it needs; with "qr" the ones
        that generate C: use it for a law to export), "banded" (the same order of solves
        with the factors in numpy: scipy's LAPACK banded LU with the regulator's
        unknowns as a border, :mod:`.banded_lu`, :mod:`.rti_banded`; refused, naming
        why, when the Jacobian's band does not pay) or "auto" (default: "sparse_lu" when
        compiled, else "banded" where the band pays (n >= 10 on the chain), else LAPACK
        LU; :attr:`~.rti.RealTimeIteration.band_reason` says why not).
    disturbance : str
        The disturbance model of the NMPC's own Kalman filter on the states it reads
        (:class:`~.disturbance.StateDisturbanceFilter`): "load" (the load mass), "input",
        "output" or "none" (default here: the bare law, what the controller FMU exports;
        :func:`make_nmpc` defaults to "load" where the model has a load, else "input",
        when no EKF runs). Its estimate is fed to the prediction's run-time parameters
        every sample.
    input_std, output_std : float or None
        The filter's noise: of the input [Pa] (default 2 kPa, the EKF's and the LMPC's)
        and of the tracked output as read [SI] (None: :data:`~.ekf.DEFAULT_STD` of its
        unit).
    """

    horizon: int = 20
    weight_y: float = 1.0e6
    weight_du: float = 1.0e-9
    u_min: float = 0.0
    u_max: float = 1.0e5
    rate_max: float = 2.0e6
    soft_min: tuple = ((TENSIONS, 0.0),)
    soft_penalty: float = 1.0e6
    backoff: float = 0.0
    degree: int = 3
    qp_solver: str = "daqp"
    output: str = "myofibril.length"
    integral_gain: float = 5.0
    terminal_weight: float = 0.0
    compiled: bool = False
    linear_solver: str = "auto"
    disturbance: str = "none"
    input_std: float = 2.0e3
    output_std: float | None = None

    def __post_init__(self) -> None:
        if self.disturbance not in DISTURBANCES:
            raise ParameterError("nmpc.disturbance", self.disturbance, f"one of {DISTURBANCES}")
        check_mpc_settings("nmpc", self)
        positive("nmpc", "integral_gain", self.integral_gain, allow_zero=True)
        positive("nmpc", "terminal_weight", self.terminal_weight, allow_zero=True)
        positive("nmpc", "backoff", self.backoff, allow_zero=True)
        if not isinstance(self.compiled, bool):
            raise ParameterError("nmpc.compiled", self.compiled, "true or false")
        if self.qp_solver not in QP_SOLVERS:
            raise ParameterError("nmpc.qp_solver", self.qp_solver, f"one of {sorted(QP_SOLVERS)}")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ParameterError(
                "nmpc.linear_solver", self.linear_solver, f"one of {LINEAR_SOLVERS}"
            )
        count("nmpc.degree", self.degree, 1, 5, "Radau IIA of order 1 to 9")


class NonlinearMPC(RecedingHorizon):
    """Nonlinear MPC of the tracked output by the regulator command (module docstring).

    Reads every state of the prediction model and the tracked output by name (state
    feedback: the plant's signals of the same names, or an estimator's).

    Parameters
    ----------
    model : Model
        The prediction model (smooth flow law, ``saturate=False``).
    u_op : numpy.ndarray
        The input held before the first sample [SI].
    dt : float
        Sample time [s].
    settings : NMPCSettings, optional
    params : mapping of str to float, optional
        Parameter overrides of ``model`` by name (SI), e.g. the plant's load.

    Examples
    --------
    >>> from sarcomere.dynamics import hanging_load, solve_equilibrium
    >>> m = hanging_load(1, load_kg=0.02, flow_law="smooth", saturate=False)
    >>> eq = solve_equilibrium(m, {"regulator.p_cmd": 5e4})
    >>> mpc = NonlinearMPC(m, eq.u, 0.01)
    >>> y = {n: eq[n] for n in mpc.outputs}
    >>> u = mpc.checked(0.0, y, {"myofibril.length": eq["myofibril.length"]})
    >>> round(u["regulator.p_cmd"])
    50000
    """

    slug = "nmpc"

    def __init__(
        self,
        model: Model,
        u_op: np.ndarray,
        dt: float,
        settings: NMPCSettings | None = None,
        params: Mapping[str, float] | None = None,
    ) -> None:
        s = settings or NMPCSettings()
        if model.nz:
            raise ParameterError("nmpc.model", model.name, "an ODE model (no algebraic unknowns)")
        self.bounds = soft_bounds("nmpc", model, s.soft_min, s.soft_penalty)
        # after the model parameters: the input and output disturbances, the back-offs
        backoffs = [f"backoff.{n}" for n, _, _ in self.bounds] if s.backoff else []
        self.offsets = (*OFFSETS, *backoffs)
        super().__init__(model, dt, s, [*model.state_names, s.output], params)
        # state scales: the largest magnitude at the ends of the input range; states that
        # are zero there (velocities) get 1 cm/s
        big = np.abs(np.vstack([e.x for e in self.clip.ends])).max(axis=0)
        pb = Prediction(model, s, self.dt, np.where(big > 1e-12, big, 1e-2), self.bounds)
        self.problem = pb
        self.engine = self.build_engine(pb)
        self.disturbance = check_disturbance("nmpc", s.disturbance, model.param_names)
        self.filter = self._disturbance_filter(pb.xs)
        self.reset(u_op)

    @property
    def uncertain_signals(self) -> list[str]:
        """The bounded signals whose estimate's standard deviation raises their bound (by
        ``backoff`` times it), fed as the run-time parameters ``backoff.<signal>``
        [SI] by the EKF the NMPC runs on (:class:`~.estimated.OnEstimate`); none without
        ``backoff``."""
        return [n for n, _, _ in self.bounds] if self.settings.backoff else []

    def build_engine(self, pb: Prediction) -> RealTimeIteration:
        """The optimiser of every sample: the real-time iteration (the speed study's
        converged NLP replaces it, with :meth:`optimise`)."""
        return RealTimeIteration(pb)

    def _disturbance_filter(self, xs: np.ndarray) -> StateDisturbanceFilter | None:
        """The Kalman filter of :attr:`NMPCSettings.disturbance` (None for "none"), its
        estimate kept in the range of the load, +-the input range or +-the reachable
        output span."""
        s, m, kind = self.settings, self.model, self.disturbance
        if kind == "none":
            return None
        if kind == "load":
            var = m.variables["load.m"]
            bounds = (var.low, var.high)
        else:
            span = s.u_max - s.u_min if kind == "input" else self.clip.high - self.clip.low
            bounds = (-span, span)
        y_std = s.output_std or DEFAULT_STD.get(m.unit(s.output), 1e-6)
        return StateDisturbanceFilter(m, s.output, kind, self.dt, xs, s.input_std, y_std, bounds)

    @property
    def disturbance_estimate(self) -> float:
        """The own filter's estimate now [SI]: the load mass [kg], the input offset [Pa],
        the output offset [SI]; 0 for "none"."""
        return 0.0 if self.filter is None else float(self._p[self.filter.index])

    def reset(self, u0: Mapping[str, float] | np.ndarray) -> None:
        super().reset(u0)
        self._offset = 0.0
        self.violation = 0.0  # the last QP answer's (scaled rows, see rti.QP_FEASIBLE)
        self.slack = 0.0  # the last plan's largest slack of a soft bound [SI]
        if self.filter is not None:
            self.filter.reset()
        self.engine.reset()

    def law_function(self) -> cs.Function:
        """The RTI's whole per-sample law as one pure CasADi Function::

            nmpc_law(memory, x, u_prev, ref, p)
                -> (memory_next, u, violation, fallback, slack)

        ``memory`` (zeros at the start) carries the guess and the plan between samples
        (:class:`~.rti.RealTimeIteration`), ``x`` the state [SI, ``model.state_names``],
        ``u_prev`` the input held [SI], ``ref`` the reference at nodes 1..horizon [SI, as
        the optimiser sees it: clipped, shifted by the integral action], ``p`` the
        prediction's parameters [SI, :attr:`runtime_parameters`]; ``u`` the command [SI],
        ``violation`` the QP answer's, ``fallback`` 1 when the sample fell back, ``slack``
        the plan's largest slack of a soft bound [SI]. This
        controller calls exactly these Functions each sample (split: ``engine.sample``).
        For C generation build the controller with ``linear_solver="sparse_lu"`` (or
        "qr"): LAPACK (the uncompiled default "lapacklu") has no code generation. The
        QP solver DAQP's generated C includes ``daqp/api.h`` and links statically
        against ``libdaqpstat.a``, both in the casadi wheel (``casadi/include``,
        :func:`.rti_compiled.daqp_build`).
        """
        return self.engine.law

    @property
    def memory(self) -> np.ndarray:
        """The RTI's memory vector now (a copy; see :meth:`law_function`)."""
        return self.engine.memory.copy()

    def observe(self, x: np.ndarray, u_held: np.ndarray, y: Mapping[str, float]) -> None:
        """The own filter's disturbance estimate from this sample into the parameters."""
        if self.filter is not None:
            out = float(y[self.settings.output])
            self._p[self.filter.index] = self.filter.update(x, u_held, out, self._p)

    def optimise(self, x: np.ndarray, ref: np.ndarray, y: Mapping[str, float]) -> dict:
        """One sample of the real-time iteration from the state ``x`` [SI] to the
        reference per node ``ref`` (as the optimiser sees it); the command by name. Real
        time: the command comes from the preparation made between samples with the last
        estimate (the filter's prior for this sample: its disturbance is a random walk);
        this sample's estimate (:meth:`observe`), made after the command, goes into the
        next preparation."""
        eng, u_prev = self.engine, self._u.copy()
        u, viol, fallback, slack = eng.sample(x, u_prev, ref, self._p)
        self.stats.fallbacks += int(fallback[0])
        self.violation, self.slack = float(viol[0]), float(slack[0])
        self._plan = eng.memory[eng.slices["plan"]].reshape(-1, len(u_prev))
        self._u = u
        self.observe(x, u_prev, y)
        eng.prepare_next(x, self._u, self._p)
        return dict(zip(self.inputs, self._u.tolist(), strict=True))

    def update(self, t: float, y: Mapping[str, float], r: Mapping[str, float]) -> dict:
        x = np.array([y[n] for n in self.model.state_names], dtype=float)
        ref = self.clip(r)
        # the reference per node: the preview if given for this sample, else r(t) held;
        # integral action shifts it by the integrated error, kept inside the reachable range
        nodes = self.nodes(ref)
        shifted = np.clip(nodes + self._offset, self.clip.low, self.clip.high)
        u_prev = self._u.copy()
        u = self.optimise(x, shifted, y)
        # anti-windup: no integration while the command is held by a bound or moves at
        # the rate limit (the optimiser could not follow a larger shift either)
        at_rate = np.abs(self._u - u_prev) >= self.settings.rate_max * self.dt * (1 - 1e-6)
        at_bound = (self._u <= self._u_lo) | (self._u >= self._u_hi)
        if not np.any(at_rate | at_bound):
            error = ref - float(y[self.settings.output])
            self._offset += self.settings.integral_gain * self.dt * error
        return u


DEFAULT_FIDELITY = "full"
"""Prediction fidelity of :func:`make_nmpc`, chosen by measurement (BENCHMARKS.md, section
5; ``sarcomere bench mpc``): on the full exact-law plant (n = 3, 20 g, RTI) full and
quasi_static track equally (0.815 mm RMS before the load step) and hold a raised tension
bound to 2e-5 N, and full was the faster of the two; symmetric is about 4x faster and
tracks 6 % worse, but has one representative thread, so it cannot bound the lowest
thread's tension."""


EKF_BACKOFF = 1.0
"""The ``backoff`` :func:`make_nmpc` gives an NMPC on an EKF [-]: its bounds raised by one
standard deviation of the estimate. Measured on control-tension (the 0.2 N bound; the NMPC
on the EKF, everything else as packaged): 0 broke the bound on the plant by 1.76 mN (for
30 ms), 1 by 0.35 mN (RMS error 0.67 mm against 0.47 mm), 2 and 3 not at all but at
1.30 and 2.62 mm RMS; 1 is the smallest of these that holds it within 1 mN."""


def make_nmpc(model: Model, op: Equilibrium, dt: float, settings: dict) -> Controller:
    """Registry factory of ``nmpc`` for the paper's set-ups.

    The prediction model is the plant's set-up rebuilt for optimisers at the fidelity
    ``fidelity`` (own key, default :data:`DEFAULT_FIDELITY`), with the smooth flow law and
    no clamp: by the scene's ``build_model`` where given, else by the set-up the plant
    records (:attr:`Model.setup`, set by :func:`~sarcomere.dynamics.assemblies.hanging_load`
    and :func:`~sarcomere.dynamics.assemblies.isometric`); its parameters take the plant's
    values by name (``op.p``: load, fixture position, regulator, geometry, the scene's
    overrides).
    Common keys: ``output``, ``input``, ``u_min``, ``u_max``, ``tension_min`` (every
    thread tension >= it, soft, default 0; added to the own key ``soft_min``,
    :func:`~.receding.factory_bounds`). Own keys: the other :class:`NMPCSettings` fields,
    ``fidelity``, ``estimator`` ("none" or "ekf"), ``ekf`` and ``disturbance`` ("load",
    "input", "output" or "none"). Without an estimator the NMPC's own Kalman filter on
    the states it reads estimates the disturbance (:attr:`NMPCSettings.disturbance`,
    default "load" where the prediction has a load, else "input", as the LMPC's); on an
    EKF the EKF does (:func:`~.receding.ekf_disturbance`, default its own: the load where
    the plant has one) and the NMPC's filter is off. The output's noise (``noise_std``)
    sets ``output_std`` unless given. Whichever estimates a parameter of the prediction
    or an offset, the estimate is fed to the prediction every sample and
    ``integral_gain`` defaults to 0 (set it to keep the integral reference shift as
    well; ``disturbance = "none"`` without an EKF keeps the integral's default 5 1/s). On
    an EKF ``backoff`` defaults to :data:`EKF_BACKOFF`.
    """
    extra = {"fidelity": DEFAULT_FIDELITY, "disturbance": None}
    own, est, ekf_settings = mpc_settings("nmpc", model, settings, NMPCSettings, extra, 0.0)
    kind = own.pop("disturbance")
    if est == "ekf":  # the EKF estimates the disturbance: no second estimate
        ekf_settings = ekf_disturbance("nmpc", model, kind, ekf_settings)
    given = dict(zip(model.param_names, np.asarray(op.p, float), strict=True))
    fidelity = own.pop("fidelity")
    smooth = {"fidelity": fidelity, "flow_law": "smooth", "saturate": False}
    if settings.get("build_model") is not None:  # a scene: its own set-up, rebuilt
        pred = settings["build_model"](**smooth)
    elif model.setup is not None:  # an assembly's model: the set-up it records
        pred = model.setup.build(**smooth)
    else:
        raise ParameterError(
            "nmpc.model",
            model.name,
            "a model built by an assembly (hanging_load, isometric), or a build_model setting",
            "a System flattened by hand records no set-up to rebuild for prediction",
        )
    params = {n: given[n] for n in pred.param_names if n in given}
    if est == "ekf":
        own["disturbance"] = "none"
        fed = any(
            n in (*pred.param_names, *OFFSETS) for n in estimated_parameters(model, ekf_settings)
        )
    else:  # the NMPC's own filter on the states it reads
        default = "load" if "load.m" in pred.param_names else "input"
        own["disturbance"] = check_disturbance("nmpc", kind or default, pred.param_names)
        fed = own["disturbance"] != "none"
    if fed and "integral_gain" not in settings:  # the estimate removes the offset
        own["integral_gain"] = 0.0
    if est == "ekf" and "backoff" not in settings:  # the estimate's uncertainty
        own["backoff"] = EKF_BACKOFF
    ctl = NonlinearMPC(pred, op.u, dt, NMPCSettings(**own), params)
    return with_estimator("nmpc", ctl, model, op, dt, settings, est, ekf_settings)


register_controller("nmpc", make_nmpc)
