"""MPC speed on the length-control scene: the real-time-iteration NMPC, the converged NMPC
(IPOPT, fatrop: :mod:`.mpc_nlp`), linear MPC and a plain CasADi ``Opti`` formulation, side by side.

**Problem.** n = 3 APS, 20 g, horizon 20, sample time 10 ms. The plant is the full model
with the exact ISO 6358 flow law and the saturating regulator, integrated by CVODES between
samples with the command held; the NMPC predicts with the smooth flow law and no clamp
(bounds [0, 0.1 MPa], rate 2 MPa/s, every thread tension >= 0). Every controller reads the
plant's states by name (state feedback).

**Scene.** From the equilibrium at 40 kPa: the length reference steps 4 mm shorter at
0.1 s, follows a 1.5 mm, 1 Hz sine around 2 mm shorter, then holds; +50 g of load at
``T_LOAD`` (the full run: 3 s; ``--quick``: the same shape in 1.5 s).

**Timing.** The time of each ``Controller.checked`` call (Python included) over the scene,
median and 95th percentile; the plant's integration is not counted. The RTI and the LMPC
run the scene ``FAST_REPEATS`` times and keep the quietest run. The RTI's time is
split into its feedback (the measurement-to-command latency: the affine update of the
condensed QP and the QP), its preparation (linearisation and condensing, and the update of
the guess, made after the command) and the Python around them; it runs in Python (CasADi's
virtual machine) and compiled (``compiled = true``: generated C, the lifted solves the
sparse LU of :mod:`sarcomere.dynamics.simulation.sparse_lu`), and the two, with the compiled one on
LAPACK's LU as a third, also run interleaved, sample by sample in one loop, for
like-for-like ratios. The plain ``Opti`` formulation
(RK4 multiple shooting with 15 substeps per interval, unscaled, ``opti.solve()`` each
sample, warm-started through ``set_initial``) and do-mpc (if installed: the same Radau
collocation, cost and tension bound through its ``MPC`` class with IPOPT; do-mpc has no
rate limit on the input, so that constraint is missing there) run on the first
``SLOW_STEPS`` samples only. The prediction fidelity of the RTI NMPC (full, quasi_static,
symmetric) is compared on the same scene (tracking error and time) and on venting with a
raised minimum tension (how far the plant's lowest thread tension breaks the bound).
"""

from __future__ import annotations

import json
import math
import statistics
import time
import warnings
from pathlib import Path

import casadi as cs
import numpy as np

from sarcomere.controllers.base import Controller
from sarcomere.controllers.lmpc import LinearMPC, LMPCSettings
from sarcomere.controllers.nmpc import NMPCSettings, NonlinearMPC
from sarcomere.controllers.receding import TENSIONS
from sarcomere.dynamics.assemblies import HOOK_MASS_KG, hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.simulation.simulator import Simulator

from .mpc_nlp import ConvergedNMPC

N_APS, LOAD_KG, DT, HORIZON = 3, 0.02, 0.01, 20
P_START = 4e4
SLOW_STEPS = {False: 15, True: 6}
"""Samples the plain Opti formulation and do-mpc run (two to three orders of magnitude
slower than the RTI): their medians are over these samples after the first."""
L_NAME, P_NAME = "myofibril.length", "regulator.p_cmd"
FAST, FAST_REPEATS = ("nmpc_rti", "nmpc_rti_compiled", "lmpc"), 3
"""The fast variants run the scene this many times and report the run with the smallest
median: the machine is shared, and a busy neighbour inflates a whole run."""


def reference(t: float, L0: float, quick: bool) -> float:
    """The length reference [m] at ``t`` [s]."""
    a, b = (0.6, 1.1) if quick else (1.0, 2.0)
    if t < 0.1:
        return L0
    if t < a:
        return L0 - 4e-3
    if t < b:
        return L0 - 2e-3 + 1.5e-3 * math.sin(2 * math.pi * (t - a))
    return L0 - 2e-3


def scene_times(quick: bool) -> tuple[float, float]:
    """End of the scene and time of the load step [s]."""
    return (1.5, 1.2) if quick else (3.0, 2.5)


class PlainOpti(Controller):
    """What a user writes first: ``casadi.Opti`` with RK4 multiple shooting (15 substeps per
    interval, unscaled), parameters set and ``opti.solve()`` called every sample."""

    slug = "opti"

    def __init__(self, model, u_op: np.ndarray, dt: float, substeps: int = 15) -> None:
        super().__init__(dt, model.input_names, [*model.state_names, L_NAME], {P_NAME: 0.0},
                         {P_NAME: 1e5})  # fmt: skip
        nx, p = model.nx, model.parameters()
        x, u = cs.MX.sym("x", nx), cs.MX.sym("u")
        f = cs.Function("f", [x, u], [model.function("ode")(x, cs.MX(0, 1), u, p)])
        h = dt / substeps
        xk = x
        for _ in range(substeps):
            k1 = f(xk, u)
            k2 = f(xk + h / 2 * k1, u)
            k3 = f(xk + h / 2 * k2, u)
            k4 = f(xk + h * k3, u)
            xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        F = cs.Function("F", [x, u], [xk])
        length = cs.Function(
            "L", [x], [model.signals_function([L_NAME])(x, cs.MX(0, 1), cs.MX(0, 1), p)]
        )
        opti = cs.Opti()
        X, U = opti.variable(nx, HORIZON + 1), opti.variable(1, HORIZON)
        self.x0, self.r, self.up = opti.parameter(nx), opti.parameter(), opti.parameter()
        opti.subject_to(X[:, 0] == self.x0)
        J = 0
        for k in range(HORIZON):
            opti.subject_to(X[:, k + 1] == F(X[:, k], U[k]))
            prev = self.up if k == 0 else U[k - 1]
            opti.subject_to(opti.bounded(-2e4, U[k] - prev, 2e4))
            J += 1e6 * (length(X[:, k + 1]) - self.r) ** 2 + 1e-9 * (U[k] - prev) ** 2
        opti.subject_to(opti.bounded(0, U, 1e5))
        opti.minimize(J)
        opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
        self.opti, self.X, self.U = opti, X, U
        self.u = float(u_op[0])
        self.sol = None

    def update(self, t, y, r):
        o = self.opti
        x0 = np.array([y[n] for n in self.outputs[:-1]])
        o.set_value(self.x0, x0)
        o.set_value(self.r, r[L_NAME])
        o.set_value(self.up, self.u)
        if self.sol is None:
            o.set_initial(self.X, np.tile(x0[:, None], (1, HORIZON + 1)))
            o.set_initial(self.U, self.u)
        else:
            o.set_initial(self.sol.value_variables())
        try:
            self.sol = o.solve()
            self.u = float(np.clip(self.sol.value(self.U)[0], 0.0, 1e5))
        except RuntimeError:
            self.stats.fallbacks += 1
            self.sol = None
        return {P_NAME: self.u}


class DoMPC(Controller):
    """The same NMPC through do-mpc (an optional benchmark dependency)."""

    slug = "do_mpc"

    def __init__(self, model, u_op: np.ndarray, dt: float) -> None:
        with warnings.catch_warnings():  # its optional features announce themselves
            warnings.simplefilter("ignore")
            import do_mpc

        super().__init__(dt, model.input_names, [*model.state_names, L_NAME], {P_NAME: 0.0},
                         {P_NAME: 1e5})  # fmt: skip
        p, none = model.parameters(), cs.SX(0, 1)
        dm = do_mpc.model.Model("continuous", "SX")
        x = dm.set_variable("_x", "x", shape=(model.nx, 1))
        u = dm.set_variable("_u", "p_cmd")
        ref = dm.set_variable("_tvp", "ref")
        dm.set_rhs("x", model.function("ode")(x, none, u, p))
        names = [n for n in model.signal_names if n.startswith("myofibril.actin")]
        sig = model.signals_function([L_NAME, *[n for n in names if n.endswith(".T")]])
        out = sig(x, none, u, p)
        dm.set_expression("L", out[0])
        dm.set_expression("T", out[1:])
        dm.setup()
        mpc = do_mpc.controller.MPC(dm)
        st = mpc.settings
        st.n_horizon, st.t_step, st.state_discretization = HORIZON, dt, "collocation"
        st.collocation_type, st.collocation_deg, st.collocation_ni = "radau", 3, 1
        st.store_full_solution = False
        st.supress_ipopt_output()
        track = 1e6 * (dm.aux["L"] - ref) ** 2
        mpc.set_objective(lterm=track, mterm=track)
        mpc.set_rterm(p_cmd=1e-9)
        mpc.bounds["lower", "_u", "p_cmd"], mpc.bounds["upper", "_u", "p_cmd"] = 0.0, 1e5
        mpc.set_nl_cons("T", -dm.aux["T"], ub=0.0)
        eq = solve_equilibrium(model, {P_NAME: 1e5})
        mpc.scaling["_x", "x"] = np.where(np.abs(eq.x) > 1e-12, np.abs(eq.x), 1e-2)
        mpc.scaling["_u", "p_cmd"] = 1e5
        self.tvp, self.ref = mpc.get_tvp_template(), 0.0

        def tvp_fun(t):
            self.tvp["_tvp", :, "ref"] = self.ref
            return self.tvp

        mpc.set_tvp_fun(tvp_fun)
        with warnings.catch_warnings():  # do-mpc's own checks call numpy on CasADi values
            warnings.simplefilter("ignore", FutureWarning)
            mpc.setup()
        self.mpc, self.u0 = mpc, u_op
        self.started = False

    def update(self, t, y, r):
        x = np.array([y[n] for n in self.outputs[:-1]]).reshape(-1, 1)
        self.ref = r[L_NAME]
        if not self.started:
            self.mpc.x0, self.mpc.u0 = x, self.u0
            self.mpc.set_initial_guess()
            self.started = True
        u = float(np.clip(np.ravel(self.mpc.make_step(x))[0], 0.0, 1e5))
        return {P_NAME: u}


def run_scene(make, quick: bool, steps: int | None = None) -> dict:
    """Close the loop on the exact-law plant; timing and tracking of one controller.
    ``first_samples_median_ms``: the median over the samples the slow variants run
    (after the first), for a like-for-like ratio with them."""
    plant = hanging_load(N_APS, load_kg=LOAD_KG)
    eq = solve_equilibrium(plant, {P_NAME: P_START})
    ctl = make(eq)
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    t_end, t_load = scene_times(quick)
    n_steps = round(t_end / DT) if steps is None else steps
    L0, errors, loaded = eq[L_NAME], [], False
    for _ in range(n_steps):
        if not loaded and sim.t >= t_load - 1e-9:
            sim.reset(x0=sim.x, params={"load.m": HOOK_MASS_KG + LOAD_KG + 0.05}, t0=sim.t)
            loaded = True
        y = sim.signals(ctl.outputs)
        ref = reference(sim.t, L0, quick)
        u = ctl.checked(sim.t, y, {L_NAME: ref})
        errors.append((sim.t, y[L_NAME] - ref))
        sim.step(u, DT)
    times = np.array(ctl.stats.solve_times_s[1:] or ctl.stats.solve_times_s) * 1e3
    e = np.array(errors)
    before = e[e[:, 0] < t_load, 1]
    return {
        "steps": n_steps,
        "step_median_ms": float(np.median(times)),
        "step_p95_ms": float(np.percentile(times, 95)),
        "first_samples_median_ms": float(np.median(times[: SLOW_STEPS[quick] - 1])),
        "rmse_mm": float(np.sqrt(np.mean(np.square(e[:, 1]))) * 1e3),
        "rmse_before_load_mm": float(np.sqrt(np.mean(np.square(before))) * 1e3),
        "fallbacks": ctl.stats.fallbacks,
        "controller": ctl,
    }


TENSION_MIN = 0.2
"""Raised minimum thread tension [N] of the venting test (the lowest thread carries 0.206 N
at rest at 0.1 MPa with 20 g)."""


def tension_scene(fidelity: str, steps: int = 40) -> dict:
    """Vent from 0.1 MPa towards the longest length with every thread tension >= 0.2 N: the
    lowest plant tension seen, and by how much it broke the bound."""
    plant = hanging_load(N_APS, load_kg=LOAD_KG)
    eq = solve_equilibrium(plant, {P_NAME: 1e5})
    s = NMPCSettings(horizon=HORIZON, soft_min=((TENSIONS, TENSION_MIN),))
    ctl = NonlinearMPC(_prediction(fidelity), eq.u, DT, s)
    names = [n for n in plant.signal_names if n.startswith("myofibril.actin") and n[-2:] == ".T"]
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    lowest = math.inf
    for _ in range(steps):
        y = sim.signals([*ctl.outputs, *names])
        lowest = min(lowest, *(y[n] for n in names))
        sim.step(ctl.checked(sim.t, y, {L_NAME: ctl.clip.high}), DT)
    return {"lowest_tension_N": lowest, "violation_N": max(TENSION_MIN - lowest, 0.0)}


def _prediction(fidelity: str = "full"):
    return hanging_load(N_APS, load_kg=LOAD_KG, fidelity=fidelity, flow_law="smooth",
                        saturate=False)  # fmt: skip


class Timed:
    """A callable that records the wall time (``times``) and this thread's CPU time
    (``cpu``) of each call of ``f`` [s]: on a shared machine the wall time also counts the
    time the process waited for a core."""

    def __init__(self, f) -> None:
        self.f, self.times, self.cpu = f, [], []

    def __call__(self, *args):
        tic, cpu = time.perf_counter(), time.thread_time()
        out = self.f(*args)
        self.times.append(time.perf_counter() - tic)
        self.cpu.append(time.thread_time() - cpu)
        return out


def timed_rti(model, compiled: bool = False, linear_solver: str = "auto"):
    """An RTI NMPC whose three Functions (prepare, feedback, update) are timed apart: the
    feedback call is the measurement-to-command latency."""

    def make(eq):
        s = NMPCSettings(horizon=HORIZON, compiled=compiled, linear_solver=linear_solver)
        ctl = NonlinearMPC(model, eq.u, DT, s)
        calls = ctl.engine.calls
        for name in calls:
            calls[name] = Timed(calls[name])
        return ctl

    return make


def _split(row: dict) -> None:
    """Add the RTI's feedback latency and preparation time per step (median, p95) [ms]
    from its timed calls (the first sample, which prepares at the measurement, left out)."""
    calls = row["controller"].engine.calls
    for clock, tag in (("times", ""), ("cpu", "_cpu")):
        feedback = np.array(getattr(calls["feedback"], clock)[1:]) * 1e3
        row[f"feedback{tag}_median_ms"] = float(np.median(feedback))
        row[f"feedback{tag}_p95_ms"] = float(np.percentile(feedback, 95))
        n = len(feedback) + 1
        prep = sum(np.array(getattr(calls[k], clock)[1:n]) for k in ("prepare", "update"))
        row[f"prepare_update{tag}_median_ms"] = float(np.median(prep * 1e3))
        row[f"rti_calls{tag}_median_ms"] = float(np.median(prep * 1e3 + feedback))


def interleaved_rti(quick: bool) -> dict:
    """The RTI in Python, compiled (its lifted solves the generated sparse LU) and compiled
    with LAPACK's LU (as before the sparse LU) on the same scene in one loop, sample by
    sample (the same machine load for all): the plant follows the Python one; the compiled
    ones get the same measurements. Medians [ms] of each one's feedback and whole step,
    their ratios, and the largest command difference to the Python one's [Pa]."""
    pred = _prediction()
    plant = hanging_load(N_APS, load_kg=LOAD_KG)
    eq = solve_equilibrium(plant, {P_NAME: P_START})
    ctls = {
        "python": timed_rti(pred)(eq),
        "compiled": timed_rti(pred, True)(eq),
        "compiled_lapack": timed_rti(pred, True, "lapacklu")(eq),
    }
    sim = Simulator(plant)
    sim.reset(x0=eq.x)
    t_end, t_load = scene_times(quick)
    worst, loaded = 0.0, False
    steps_cpu = {k: [] for k in ctls}
    for _ in range(round(t_end / DT)):
        if not loaded and sim.t >= t_load - 1e-9:
            sim.reset(x0=sim.x, params={"load.m": HOOK_MASS_KG + LOAD_KG + 0.05}, t0=sim.t)
            loaded = True
        y = sim.signals(ctls["python"].outputs)
        r = {L_NAME: reference(sim.t, eq[L_NAME], quick)}
        u = {}
        for k, c in ctls.items():
            cpu = time.thread_time()
            u[k] = c.checked(sim.t, y, r)[P_NAME]
            steps_cpu[k].append(time.thread_time() - cpu)
        worst = max(worst, *(abs(u["python"] - u[k]) for k in u))
        sim.step({P_NAME: u["python"]}, DT)
    out = {"max_command_difference_Pa": worst}
    for name, c in ctls.items():
        row = {"controller": c}
        _split(row)
        row.pop("controller")
        row["step_median_ms"] = float(np.median(c.stats.solve_times_s[1:]) * 1e3)
        row["step_p95_ms"] = float(np.percentile(c.stats.solve_times_s[1:], 95) * 1e3)
        row["step_cpu_median_ms"] = float(np.median(steps_cpu[name][1:]) * 1e3)
        row["step_cpu_p95_ms"] = float(np.percentile(steps_cpu[name][1:], 95) * 1e3)
        out[name] = row
    for k in (
        "feedback_median_ms",
        "step_median_ms",
        "feedback_cpu_median_ms",
        "step_cpu_median_ms",
    ):
        out[f"{k[:-3]}_ratio_python_to_compiled"] = out["python"][k] / out["compiled"][k]
        out[f"{k[:-3]}_ratio_lapack_to_sparse_lu"] = out["compiled_lapack"][k] / out["compiled"][k]
    return out


def study(out_dir: Path, quick: bool = False) -> dict:
    """Every MPC on the scene; writes ``mpc.json``. Returns ``result``, ``metrics``, ``files``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    pred = _prediction()

    def nmpc(solver, model=pred):
        s = NMPCSettings(horizon=HORIZON)
        if solver == "rti":
            return lambda eq: NonlinearMPC(model, eq.u, DT, s)
        return lambda eq: ConvergedNMPC(model, eq.u, DT, s, solver=solver)

    variants = {
        "nmpc_rti": timed_rti(pred),
        "nmpc_rti_compiled": timed_rti(pred, compiled=True),
        "nmpc_ipopt": nmpc("ipopt"),
        "nmpc_fatrop": nmpc("fatrop"),
        "lmpc": lambda eq: LinearMPC(
            pred,
            solve_equilibrium(pred, {P_NAME: P_START}).x,
            eq.u,
            DT,
            LMPCSettings(horizon=HORIZON),
        ),
    }
    rows = {}
    for name, make in variants.items():
        tic = time.perf_counter()
        runs = [run_scene(make, quick) for _ in range(FAST_REPEATS if name in FAST else 1)]
        rows[name] = min(runs, key=lambda r: r["step_median_ms"])
        rows[name]["medians_of_repeats_ms"] = [r["step_median_ms"] for r in runs]
        rows[name]["wall_s"] = time.perf_counter() - tic
    for name in ("nmpc_rti", "nmpc_rti_compiled"):
        _split(rows[name])
    rti = rows["nmpc_rti"]
    calls = rti["controller"].engine.calls
    casadi = sum(statistics.median(calls[k].times) for k in calls) * 1e3
    rti["python_around_ms"] = rti["step_median_ms"] - casadi
    slow = SLOW_STEPS[quick]
    rows["opti_plain"] = run_scene(lambda eq: PlainOpti(pred, eq.u, DT), quick, slow)
    if _do_mpc_status() == "installed":
        rows["do_mpc"] = run_scene(lambda eq: DoMPC(pred, eq.u, DT), quick, slow)
    interleaved = interleaved_rti(quick)
    fidelity = {}
    for fid in ("full", "quasi_static", "symmetric"):
        r = run_scene(nmpc("rti", _prediction(fid)), quick)
        keep = ("step_median_ms", "rmse_mm", "rmse_before_load_mm", "fallbacks")
        fidelity[fid] = {k: r[k] for k in keep} | tension_scene(fid)
    for r in rows.values():
        r.pop("controller")
    result = {
        "problem": f"n = {N_APS}, {LOAD_KG * 1e3:g} g, horizon {HORIZON}, dt {DT * 1e3:g} ms",
        "quick": quick,
        "variants": rows,
        "prediction_fidelity_rti": fidelity,
        "rti_interleaved": interleaved,
        "do_mpc": _do_mpc_status(),
    }
    path = out_dir / "mpc.json"
    path.write_text(json.dumps(result, indent=1))
    metrics = {f"{k}_step_median_ms": v["step_median_ms"] for k, v in rows.items()}
    metrics.update({f"{k}_rmse_before_load_mm": rows[k]["rmse_before_load_mm"] for k in variants})
    for name in ("nmpc_rti", "nmpc_rti_compiled"):
        for k in ("feedback_median_ms", "feedback_p95_ms", "step_p95_ms"):
            metrics[f"{name}_{k}"] = rows[name][k]
    for k in (
        "feedback_median_ratio_python_to_compiled",
        "step_median_ratio_python_to_compiled",
        "step_median_ratio_lapack_to_sparse_lu",
    ):
        metrics[f"rti_{k}"] = interleaved[k]
    # like for like: the RTI over the same first samples the slow variants run
    first = rti["first_samples_median_ms"]
    metrics["nmpc_speedup_vs_plain_opti"] = rows["opti_plain"]["step_median_ms"] / first
    metrics["nmpc_speedup_vs_do_mpc"] = (
        rows["do_mpc"]["step_median_ms"] / first if "do_mpc" in rows else None
    )
    metrics["nmpc_ipopt_first_samples_median_ms"] = rows["nmpc_ipopt"]["first_samples_median_ms"]
    notes = {} if "do_mpc" in rows else {"nmpc_speedup_vs_do_mpc": _do_mpc_status()}
    return {"result": result, "metrics": metrics, "files": [path], "notes": notes}


def _do_mpc_status() -> str:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import do_mpc  # noqa: F401
    except ImportError:
        return 'do-mpc not installed: pip install "sarcomere[bench]"'
    return "installed"
