"""``Fit.from_file(path).run(out)`` end to end on data simulated in the test (CVODES at
rtol 1e-10, fixed seed): estimates, the fitted parameter file, summary.json, plots, the
held-out experiment, dropped starts counted, and the experiment ranking."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.units import to_si
from sarcomere.scenarios.fit import run as run_module
from sarcomere.scenarios.fit.run import Fit

TAU = 0.065  # s, the "true" regulator lag (default 50 ms)

FIT = """\
[fit]
name = "unit"
starts = 3
seed = 4

[parameters."regulator.tau"]
start = "50 ms"
bounds = ["20 ms", "150 ms"]

[noise."myofibril.length"]
sigma = "2 um"

[[experiments]]
name = "step"
kind = "time-series"
data = "step.csv"
inputs = ["pressure"]
outputs = ["myofibril.length"]
[experiments.model]
name = "myofibril"
n = 1
[experiments.model.options]
load = "{load} g"

[[experiments]]
name = "static"
kind = "static"
data = "static.csv"
inputs = ["pressure"]
outputs = ["myofibril.length"]
validation = true
[experiments.model]
name = "myofibril"
n = 1
[experiments.model.options]
load = "{load} g"

[design]
kinds = ["step", "staircase"]
levels = ["30 kPa", "90 kPa"]
loads = ["{load} g"]
duration = "0.2 s"
sample = "4 ms"
"""


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory, tight_record):
    rng = np.random.default_rng(2)
    load = round(float(rng.uniform(20, 80)), 1)
    level = round(float(rng.uniform(30, 90)), 1)
    m = hanging_load(1, load_kg=load / 1e3)
    truth = {"regulator.tau": TAU}
    t = np.arange(0.0, 0.12 + 1e-9, 2e-3)
    u = np.where(t < 0.01, 0.0, level * 1e3)
    length = tight_record(m, t, u, truth, ["myofibril.length"])[:, 0]
    d = tmp_path_factory.mktemp("fit")
    rows = [
        f"{1e3 * a:.6f},{b / 1e3:.6f},{1e3 * c:.12g}" for a, b, c in zip(t, u, length, strict=True)
    ]
    (d / "step.csv").write_text(
        "time [ms],pressure [kPa],myofibril.length [mm]\n" + "\n".join(rows) + "\n"
    )
    static = ["pressure [kPa],myofibril.length [mm]"]
    for p in (0.0, 40.0, 80.0):
        e = solve_equilibrium(m, {"regulator.p_cmd": p * 1e3}, truth)
        static.append(f"{p},{1e3 * e['myofibril.length']:.12g}")
    (d / "static.csv").write_text("\n".join(static) + "\n")
    (d / "fit.toml").write_text(FIT.format(load=load))
    return d


@pytest.mark.slow
def test_fit_runs_end_to_end(fit_dir, monkeypatch):
    calls = []
    real = run_module.fit_from

    def second_start_fails(problem, theta0, sigma=None):
        calls.append(theta0)
        if len(calls) == 2:
            raise SolverError("simulated failure of the second start")
        return real(problem, theta0, sigma)

    monkeypatch.setattr(run_module, "fit_from", second_start_fails)
    out = fit_dir / "out"
    res = Fit.from_file(fit_dir / "fit.toml").run(out)
    value, unit = res.estimates["regulator.tau"]
    assert unit == "s" and value == pytest.approx(TAU, rel=2e-3)
    assert res.verdicts[0]["verdict"] == "identifiable"
    prof = res.profiles[0]
    assert prof.low < value < prof.high
    # the profile and Fisher intervals agree for this nearly linear problem
    lo, hi = res.fisher.interval[0]
    assert prof.low == pytest.approx(lo, rel=0.05 * (hi - lo) / value + 1e-6)
    # starts: one dropped and counted, the other two reach the best optimum
    assert len(res.starts) == 3 and sum(s.dropped for s in res.starts) == 1
    assert res.converged_starts == 2
    summary = json.loads((out / "summary.json").read_text())
    assert summary["starts"] == {
        "total": 3,
        "reached_best": 2,
        "within_chi2_1_of_best": 2,
        "dropped": 1,
        "dropped_why": ["dropped: simulated failure of the second start"],
    }
    est = summary["estimates"][0]
    assert est["unit"] == "s" and est["interval_profile_95"][0] < est["value"]
    # the held-out static curve is predicted (fit % per signal) and the record whitened
    assert summary["validation"]["static"]["myofibril.length"]["fit_percent"] > 99.0
    assert "ljung_box_p" in summary["fitted"]["step"]["myofibril.length"]
    # the record's step grid, and its integration error at the fit, in units of its noise
    grid = summary["integration"]["step"]
    assert grid["samples_per_step"] >= 1 and 1 <= grid["intervals"] <= grid["steps"]
    assert 0 <= grid["error_per_noise"]["myofibril.length"] <= 0.05, grid
    # the experiment ranking: four candidates, best first, each naming a parameter
    gains = [r["gain"] for r in summary["design"]]
    assert len(gains) == 4 and gains == sorted(gains, reverse=True) and gains[0] > 0
    assert {r["pins"] for r in summary["design"]} == {"regulator.tau"}
    # the fitted parameter file: TOML, the value with its unit, a source naming the fit
    fitted = tomllib.loads((out / "fitted.toml").read_text())
    assert fitted["fitted"]["fit"] == "unit"
    assert to_si(fitted["parameters"]["regulator.tau"], "s") == pytest.approx(value, rel=1e-9)
    assert "fitted by sarcomere fit 'unit' to step" in fitted["sources"]["regulator.tau"]
    names = {p.name for p in out.iterdir()}
    assert {"fit-step.png", "validation-static.png", "profiles.png", "correlation.png"} <= names


def test_starts_at_the_best_and_statistically_the_same():
    """Along a flat valley few starts end within 1e-5 of the best cost while all end
    within chi-squared 1 of it: both counts, a dropped start in neither."""
    from types import SimpleNamespace

    from sarcomere.scenarios.fit.run import FitResult, Start

    costs = [5897.05, 5897.08, 5897.6, 5898.2]
    starts = [Start([1.0], [1.0], c, "converged", False) for c in costs]
    starts.append(Start([1.0], None, float("inf"), "dropped: no convergence", True))
    res = SimpleNamespace(solution=SimpleNamespace(cost=5897.05), starts=starts)
    assert FitResult.converged_starts.fget(res) == 2  # 0.03 < 1e-5 * 5897
    assert FitResult.equivalent_starts.fget(res) == 3  # 0.55 < 1, 1.15 > 1
