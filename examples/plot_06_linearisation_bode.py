"""
Linearisation and a Bode plot against the nonlinear model
=========================================================

:func:`~sarcomere.controllers.linearize` gives the exact linearisation of the flattened
model at an operating point (CasADi's Jacobians, the algebraic unknowns eliminated) as a
python-control ``StateSpace`` with named signals. Its Bode plot is checked here against
the nonlinear model itself: a small sine of the regulator command around the operating
point, simulated until periodic, and the first harmonic of the length fitted at each
frequency.
"""

import control
import matplotlib.pyplot as plt
import numpy as np

from sarcomere.controllers import classify_poles, linearize, operating_point
from sarcomere.dynamics import Sine, hanging_load, simulate

model = hanging_load(n=3, load_kg=0.02)
op = operating_point(model, {"regulator.p_cmd": 5e4})  # 50 kPa, 20 g
sys = linearize(model, op, ["myofibril.length"])
for pole in classify_poles(model, sys):
    print(f"{pole['mode']:>10}: {pole['real_1_s']:8.2f} {pole['imag_1_s']:+8.2f}j 1/s")

freqs = np.logspace(-1, 1.3, 200)  # Hz
mag, phase, _ = control.frequency_response(sys, 2 * np.pi * freqs)

# %%
# The nonlinear model, excited by +-2 kPa about 50 kPa: after 6 periods of settling,
# the length's first harmonic over 4 periods, by least squares.

amp, probes = 2e3, [0.2, 0.5, 1.0, 2.0, 5.0, 10.0]
measured = []
for f in probes:
    period = 1.0 / f
    t_out = np.linspace(6 * period, 10 * period, 400)
    sine = Sine(amplitude=amp, frequency=f, offset=5e4)
    res = simulate(model, t_out[-1], inputs={"regulator.p_cmd": sine}, x0=op.x, t_out=t_out)
    y = res["myofibril.length"]
    basis = np.column_stack([np.sin(2 * np.pi * f * t_out), np.cos(2 * np.pi * f * t_out)])
    (a, b, _), *_ = np.linalg.lstsq(np.column_stack([basis, np.ones_like(t_out)]), y, rcond=None)
    measured.append((np.hypot(a, b) / amp, np.arctan2(b, a)))
measured = np.array(measured)

fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
ax_m.loglog(freqs, mag * 1e3, label="linearisation")
ax_m.loglog(probes, measured[:, 0] * 1e3, "o", label="nonlinear model, +-2 kPa")
ax_m.set_ylabel("|length / command| [mm/Pa]")
ax_m.legend()
ax_p.semilogx(freqs, np.degrees(np.unwrap(phase)))
ax_p.semilogx(probes, np.degrees(np.unwrap(measured[:, 1])), "o")
ax_p.set_ylabel("phase [deg]")
ax_p.set_xlabel("frequency [Hz]")
fig.tight_layout()
