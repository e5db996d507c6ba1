"""
A design study: a grid and Sobol' indices
=========================================

A :class:`~sarcomere.scenarios.Study` varies a scene over named factors with units and
runs every sample on Dask into a resumable Zarr store (``docs/studies.md``); it returns
an xarray Dataset. Two small studies of the 50 g step: a grid over load and pressure
(a design map of the stroke), then Sobol' indices of the stroke over three factors, from
16 base samples only (the bars' intervals say how rough that is; the packaged
``sensitivity-step`` takes 256).

A script that runs a study on the embedded cluster does it under
``if __name__ == "__main__":`` (each worker process imports the script again).
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from sarcomere.scenarios import Study
from sarcomere.scenarios.explore import analysis

GRID = """
[study]
kind = "grid"
base = "step-50g"
[study.grid]
load = ["0 g", "50 g", "100 g"]
pressure = {from = "0.04 MPa", to = "0.12 MPa", num = 4}
[study.metrics]
names = ["stroke", "rise_time"]
[solver]
method = "radau"
"""

SOBOL = """
[study]
kind = "sensitivity"
base = "step-50g"
seed = 3
[study.sensitivity]
method = "sobol"
base_count = 16
metrics = ["stroke"]
[study.factors.load]
uniform = ["40 g", "60 g"]
[study.factors."aps.A_p"]
uniform = ["0.9", "1.1"]
relative = true
[study.factors."aps.k_s"]
uniform = ["0.9", "1.1"]
relative = true
[study.metrics]
names = ["stroke"]
[solver]
method = "radau"
"""

if __name__ == "__main__":
    folder = Path(tempfile.mkdtemp())
    (folder / "grid.toml").write_text(GRID)
    (folder / "sobol.toml").write_text(SOBOL)

    grid = Study.from_file(folder / "grid.toml").run(folder / "grid", workers=2, progress=False)
    print(grid.stroke.shape, "grid points")
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for load in grid["load"].values:
        stroke = grid.stroke.sel(load=load) * 1e3
        ax.plot(grid["pressure"] / 1e3, stroke, "o-", label=f"{load * 1e3:.0f} g")
    ax.set_xlabel("step pressure [kPa]")
    ax.set_ylabel("stroke [mm]")
    ax.legend(title="load")
    fig.tight_layout()

    study = Study.from_file(folder / "sobol.toml")
    ds = study.run(folder / "sobol", workers=2, progress=False)
    indices = analysis.sobol(ds, study.definition)
    stroke = indices.sel(metric="stroke")
    st, s1 = stroke.ST.to_series(), stroke.S1.to_series()
    print(f"{ds.sizes['sample']} samples; total indices of the stroke (95 % interval):")
    for factor in st.index:
        print(f"  {factor:>8}: {st[factor]:.2f} +- {float(stroke.ST_conf.sel(factor=factor)):.2f}")
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(range(len(st)), st.values, yerr=stroke.ST_conf.values, label="total $S_T$")
    ax.bar(range(len(s1)), s1.values, width=0.4, label="first order $S_1$")
    ax.set_xticks(range(len(st)), st.index)
    ax.set_ylabel("Sobol' index of the stroke")
    ax.legend()
    fig.tight_layout()
