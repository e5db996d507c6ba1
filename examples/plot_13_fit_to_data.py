"""
Fitting the model to measured data
==================================

A fit file (``docs/fitting.md``) names the parameters to estimate with their start and
bounds, the measurement noise, and the experiments with their data. Here a small one,
written from Python beside a copy of the packaged synthetic ``step-50g`` record (made
with a known truth: ``regulator.tau`` = 75 ms, ``aps.c_e`` = 2.8 N s/m, 51.4 g at the
hook; ``scenarios/fits/fit-synthetic.toml`` fits all of them and more):
:meth:`Fit.from_file(...).run() <sarcomere.scenarios.fit.Fit.run>` fits by multiple
shooting from the start values, then says with what interval (Fisher, 95 %) and verdict each
estimate is determined. The profiles are skipped here to keep it short. The chamber's
filling and the series damping stay at their defaults (the truth differs): the residual's
transient shows the misfit that leaves.
"""

import tempfile
from importlib import resources
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from sarcomere.scenarios.fit import Fit

folder = Path(tempfile.mkdtemp())
data = resources.files("sarcomere.scenarios.fits") / "data" / "step-50g.csv"
lines = data.read_text().splitlines()
# the header lines, then every 5th sample of the 1 kHz record (200 Hz: a quicker fit)
(folder / "step-50g.csv").write_text("\n".join(lines[:2] + lines[2::5]) + "\n")
(folder / "my-fit.toml").write_text(
    """
[fit]
name = "my-fit"
method = "multiple-shooting"
starts = 1

[parameters."regulator.tau"]
start = "50 ms"
bounds = ["10 ms", "500 ms"]

[parameters."aps.c_e"]
start = "2 N*s/m"
bounds = ["0.2 N*s/m", "20 N*s/m"]

[parameters."load.m"]
start = "60 g"
bounds = ["20 g", "200 g"]

[noise."myofibril.length"]
sigma = "20 um"

[noise."myofibril.aps1.chamber.p_gauge"]
sigma = "0.5 kPa"

[[experiments]]
name = "step-50g"
kind = "time-series"
data = "step-50g.csv"
inputs = ["pressure"]
outputs = ["myofibril.length", "myofibril.aps1.chamber.p_gauge"]
[experiments.model]
name = "myofibril"
n = 3
[experiments.model.options]
setup = "hanging"
"""
)
result = Fit.from_file(folder / "my-fit.toml").run(profiles=False)

# %%
# The estimates with their 95 % intervals (from the Fisher information, on the log
# scale the fit searches in) and the verdicts.

for k, ((name, (value, unit)), v) in enumerate(
    zip(result.estimates.items(), result.verdicts, strict=True)
):
    low, high = result.fisher.interval[k]
    print(f"{name:15s} {value:.4g} {unit}  [{low:.4g}, {high:.4g}]  {v['verdict']}")
print(f"{result.converged_starts} of {len(result.starts)} starts at the best optimum")

# %%
# Measured against fitted, and the residual (``result.metrics``: per experiment and
# signal, the data, the prediction at the estimate and the fit in percent).

record = result.metrics["step-50g"]["myofibril.length"]
bound = result.built.experiments[0]
t = bound.table.time[np.array(record["sample"], dtype=int)]
y, yh = np.array(record["data"]), np.array(record["prediction"])
fig, (ax, ax2) = plt.subplots(2, 1, figsize=(6, 4.5), sharex=True)
ax.plot(t, y * 1e3, ".", ms=2, label="measured")
ax.plot(t, yh * 1e3, lw=1, label=f"fitted ({record['fit_percent']:.1f} %)")
ax.set_ylabel("chain length [mm]")
ax.legend()
ax2.plot(t, (y - yh) * 1e6, lw=0.7, color="C3")
ax2.set_ylabel("residual [um]")
ax2.set_xlabel("time [s]")
fig.tight_layout()
