"""
Muscle architecture: a joint, a bundle and a valve
==================================================

Chains of APS are the fibres; a robot puts them together. Here, from Python: an
antagonistic joint (:func:`~sarcomere.dynamics.antagonistic_joint`) stiffens as both
muscles are pressurised together (co-contraction), at no change of angle; a bundle of
parallel fibres (:func:`~sarcomere.dynamics.bundle`) lifts its load by recruiting fibres
one by one; and a chain fed by a PWM-driven on/off valve
(``supply="valve_pwm"``, :class:`~sarcomere.dynamics.supply.ValveOptions`) against the
proportional regulator. The scenes ``joint-stiffness``, ``bundle-recruitment`` and
``pwm-hold`` do the same with load steps and controllers (``docs/model.md``).
"""

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.dynamics import antagonistic_joint, bundle, hanging_load, simulate, solve_equilibrium

# %%
# Joint stiffness against co-contraction: both regulators at the same command, the
# joint at rest at 0 rad; ``stiffness.K`` [N m/rad] is the static stiffness at fixed
# commands (the load torque's derivative along the equilibria, exact).

joint = antagonistic_joint(3)
levels = np.linspace(0.05e6, 0.3e6, 6)  # Pa gauge
stiffness, theta = [], []
for p in levels:
    eq = solve_equilibrium(joint, {"flexor_regulator.p_cmd": p, "extensor_regulator.p_cmd": p})
    stiffness.append(eq["stiffness.K"])
    theta.append(eq["joint.theta"])
print("K [N m/rad]:", np.round(stiffness, 4), " max |theta| [rad]:", f"{np.max(np.abs(theta)):.1e}")

# %%
# Recruitment: three fibres of three APS share a 150 g load; each fibre's regulator
# is either off or at 0.15 MPa, and the load rises with every fibre recruited.

fibres = bundle(k_fibres=3, n=3, load_kg="150 g")
lift = []
for k in range(4):
    u = {f"regulator{i}.p_cmd": (0.15e6 if i <= k else 0.0) for i in (1, 2, 3)}
    lift.append(solve_equilibrium(fibres, u)["load.s"])
lift_mm = (lift[0] - np.array(lift)) * 1e3
print("lift [mm] with 0..3 fibres recruited:", np.round(lift_mm, 2))

# %%
# A PWM valve against the regulator: three APS with 20 g, the valve (0.3 MPa supply,
# 50 Hz) at a duty cycle of 0.4 from rest, its averaged level (the duty-weighted mean of
# the pulses), and the regulator commanded to the averaged valve's chamber pressure
# (:func:`~sarcomere.dynamics.fidelity.ripple.choose_level` says when the averaged level
# is close enough to the pulses).

duty, stop = 0.4, 0.8
switched = hanging_load(3, load_kg="20 g", supply="valve_pwm", valve={"frequency": "50 Hz"})
averaged = hanging_load(
    3, load_kg="20 g", supply="valve_pwm", valve={"frequency": "50 Hz", "level": "averaged"}
)
regulated = hanging_load(3, load_kg="20 g")
rest = {m: solve_equilibrium(m, {"valve.cmd": 0.0}).x for m in (switched, averaged)}
hold = solve_equilibrium(averaged, {"valve.cmd": duty})["myofibril.aps1.chamber.p_gauge"]
runs = {
    "valve, switched": simulate(
        switched, stop, inputs={"valve.cmd": duty}, x0=rest[switched], output_interval=5e-4
    ),
    "valve, averaged": simulate(
        averaged, stop, inputs={"valve.cmd": duty}, x0=rest[averaged], output_interval=5e-4
    ),
    f"regulator at {hold / 1e3:.0f} kPa": simulate(
        regulated,
        stop,
        inputs={"regulator.p_cmd": hold},
        x0=solve_equilibrium(regulated, {"regulator.p_cmd": 0.0}).x,
        output_interval=5e-4,
    ),
}
for name, r in runs.items():
    print(f"{name}: final length {r['myofibril.length'][-1] * 1e3:.2f} mm")

fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
axes[0].plot(levels / 1e6, stiffness, "o-")
axes[0].set_xlabel("co-contraction: both commands [MPa]")
axes[0].set_ylabel("joint stiffness [N m/rad]")
axes[1].bar(range(4), lift_mm)
axes[1].set_xlabel("fibres recruited")
axes[1].set_ylabel("load lifted [mm]")
for name, r in runs.items():
    axes[2].plot(r.index, r["myofibril.length"] * 1e3, lw=1, label=name)
axes[2].set_xlabel("time [s]")
axes[2].set_ylabel("chain length [mm]")
axes[2].legend(fontsize=7)
fig.tight_layout()
