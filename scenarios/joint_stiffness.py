"""Scenario kind "joint_stiffness": an antagonistic joint (``[model] name = "joint"``)
held at one angle while the co-contraction is raised step by step; at each level the
joint stiffness is measured on the nonlinear model by small load-torque steps and
compared with the exact linearisation's.

``[sweep.pressure]``: the co-contraction levels, the mean of the two commands, Pa;
``[sweep.angle]`` (optional, one value, rad, default 0): the angle held, by the
difference of the commands (found by bracketing on the equilibria). At each level the
load torque ``joint.tau_load`` steps by ``+-STEP_ANGLE K_lin`` (a step that moves the
joint by about 1 mrad) and the transient runs ``[simulation] stop_time`` (it must
settle); the measured stiffness is the central difference ``2 dtau / (theta_+ -
theta_-)`` of the angles at the end, ``K_lin`` the model's ``stiffness.K``, the static
gain of the exact linearisation at the equilibrium.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.simulation.simulate import simulate

from .binding import bind, command_range, solver_settings, time_grid
from .output import RunOutput, quantity_tag
from .plots import plot_groups
from .runner import register_runner
from .spec import Scenario

FLEX, EXT = "flexor_regulator.p_cmd", "extensor_regulator.p_cmd"
STEP_ANGLE = 1e-3
"""Angle [rad] the load-torque steps move the joint by (about): small against the
angle range, large against the integrator's tolerance."""
SETTLED = 1e-3
"""Largest relative change of the angle over the last tenth of a step's run [1]."""


def _commands(p: float, diff: float) -> dict:
    return {FLEX: p + 0.5 * diff, EXT: p - 0.5 * diff}


def _hold(sc: Scenario, model, over: dict, p: float, angle: float, rng, guess):
    """The equilibrium at co-contraction ``p`` [Pa] holding ``angle`` [rad], and the
    difference of the commands that holds it."""

    def theta(diff: float) -> float:
        return solve_equilibrium(model, _commands(p, diff), over, guess=guess)["joint.theta"]

    span = 2.0 * min(p - rng[0], rng[1] - p)
    diff = 0.0
    if abs(theta(0.0) - angle) > 1e-12:
        lo, hi = theta(-span) - angle, theta(span) - angle
        if lo * hi > 0:
            raise sc.error(
                ("sweep", "angle"),
                f"{angle:g} rad is out of reach at a co-contraction of {p / 1e6:g} MPa "
                f"(the commands' range holds [{lo + angle:.4g}, {hi + angle:.4g}] rad)",
            )
        diff = brentq(lambda d: theta(d) - angle, -span, span, xtol=1e-6, rtol=1e-14)
    return solve_equilibrium(model, _commands(p, diff), over, guess=guess), diff


def _step(sc, model, u, over, eq, dtau, grid, settings):
    """The angle's transient after the load torque steps to ``dtau`` [N m] at t = 0."""
    res = simulate(
        model,
        float(grid[-1]),
        u,
        {**over, "joint.tau_load": over.get("joint.tau_load", 0.0) + dtau},
        x0=eq.x,
        z0=eq.z,
        settings=settings,
        t_out=grid,
        signals=["joint.theta", "flexor_tendon.T", "extensor_tendon.T"],
    )
    theta = res["joint.theta"] - eq["joint.theta"]
    tail = theta[int(0.9 * len(theta)) :]
    if np.ptp(tail) > SETTLED * abs(theta[-1]):
        raise sc.error(
            ("simulation", "stop_time"),
            f"the angle has not settled after a load-torque step ({np.ptp(tail):.3g} rad "
            f"change over the last tenth, of a {abs(theta[-1]):.3g} rad response); run longer",
        )
    return res


def run_joint_stiffness(sc: Scenario, out_dir: Path) -> RunOutput:
    """Stiffness against co-contraction (module docstring)."""
    sc.refuse_unused("inputs", "outputs.tolerance", "control", "cosim")
    b = bind(sc)
    if b.setup != "joint":
        raise sc.error(("model", "name"), "kind 'joint_stiffness' needs [model] name = 'joint'")
    b.require_regulators("joint_stiffness")
    axes = {a.name: a for a in sc.sweep}
    if "pressure" not in axes or set(axes) - {"pressure", "angle"}:
        raise sc.error(("sweep",), "give [sweep.pressure] (and at most [sweep.angle])")
    if "angle" in axes and len(axes["angle"].values) != 1:
        raise sc.error(("sweep", "angle", "values"), "one angle: the joint is held at one")
    if sc.simulation is None:
        raise sc.error(("simulation",), "the load-torque steps need [simulation] stop_time")
    angle = axes["angle"].values[0] if "angle" in axes else 0.0
    model = b.build(sc.model.fidelity)
    over = dict(b.overrides)
    rng = command_range(model, over, FLEX)
    grid, settings = time_grid(sc.simulation), solver_settings(sc, model)
    rows, steps, guess = [], {}, None
    for p in axes["pressure"].values:
        if not rng[0] < p < rng[1]:
            raise sc.error(("sweep", "pressure"), f"{p / 1e6:g} MPa is outside the commands' range")
        eq, diff = _hold(sc, model, over, float(p), angle, rng, guess)
        guess = eq
        K_lin = eq["stiffness.K"]
        dtau = STEP_ANGLE * K_lin
        u = _commands(float(p), diff)
        plus, minus = (_step(sc, model, u, over, eq, s * dtau, grid, settings) for s in (1, -1))
        K_step = 2 * dtau / (plus["joint.theta"][-1] - minus["joint.theta"][-1])
        rows.append((p, diff, eq["joint.theta"], eq["joint.tau"], K_lin, K_step, eq))
        change = (plus["joint.theta"] - eq["joint.theta"]) / dtau
        steps[quantity_tag(p / 1e6, "MPa")] = Result(
            "time", "s", grid, {"compliance": change}, {"compliance": "rad/(N*m)"}
        )
    # the angle's response per unit load torque at each level: settles at 1 / K
    plot_groups(steps, {"load_steps": ("compliance",)}, out_dir, sc.name)
    p, diff, theta, tau, K_lin, K_step = (np.array(c) for c in list(zip(*rows, strict=True))[:6])
    eqs = [r[6] for r in rows]
    err = K_lin / K_step - 1.0
    tensions = {s: np.array([e[f"{s}_tendon.T"] for e in eqs]) for s in ("flexor", "extensor")}
    curve = Result(
        "pressure",
        "Pa",
        p,
        {
            "stiffness_linearised": K_lin,
            "stiffness_load_steps": K_step,
            "angle": theta,
            "command_difference": diff,
            "flexor_tension": tensions["flexor"],
            "extensor_tension": tensions["extensor"],
        },
        {
            "stiffness_linearised": "N*m/rad",
            "stiffness_load_steps": "N*m/rad",
            "angle": "rad",
            "command_difference": "Pa",
            "flexor_tension": "N",
            "extensor_tension": "N",
        },
    )
    metrics = {
        "stiffness_lowest_N_m_per_rad": float(K_step[0]),
        "stiffness_highest_N_m_per_rad": float(K_step[-1]),
        "stiffness_range_ratio": float(K_step[-1] / K_step[0]),
        "linearisation_error_max_ratio": float(np.max(np.abs(err))),
        "angle_held_rad": angle,
        "angle_deviation_max_rad": float(np.max(np.abs(theta - angle))),
    }
    if angle == 0.0:  # the symmetric pair at rest: no torque
        metrics["torque_at_rest_max_N_m"] = float(np.max(np.abs(tau)))
    return RunOutput(
        sc.name,
        sc.model.fidelity,
        f"{settings.method}; damped Newton on the exact Jacobian for the equilibria",
        metrics=metrics,
        results={"stiffness": curve},
        extra={"setup": b.setup, "torque_step_angle_rad": STEP_ANGLE},
    )


register_runner("joint_stiffness", run_joint_stiffness)
