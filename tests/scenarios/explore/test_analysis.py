"""Sensitivity analysis against closed forms: Sobol' indices of the Ishigami function and
Morris mu* of a linear model (|coefficient| x factor range); failed samples drop their
whole block and are reported, too many refuse the analysis."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

xr = pytest.importorskip("xarray")
pytest.importorskip("SALib")

from sarcomere.scenarios.explore import analysis  # noqa: E402

A_ISHIGAMI, B_ISHIGAMI = 7.0, 0.1


def ishigami_exact() -> tuple[np.ndarray, np.ndarray]:
    """Closed-form S1 and ST of the Ishigami function (x_i uniform on [-pi, pi])."""
    a, b, pi = A_ISHIGAMI, B_ISHIGAMI, math.pi
    v1 = 0.5 * (1 + b * pi**4 / 5) ** 2
    v2 = a**2 / 8
    v13 = 8 * b**2 * pi**8 / 225
    v = v1 + v2 + v13
    return np.array([v1, v2, 0.0]) / v, np.array([v1 + v13, v2, v13]) / v


def ishigami(x: np.ndarray) -> np.ndarray:
    return (
        np.sin(x[:, 0])
        + A_ISHIGAMI * np.sin(x[:, 1]) ** 2
        + B_ISHIGAMI * x[:, 2] ** 4 * np.sin(x[:, 0])
    )


def study_stub(problem, method, points, metrics=("y",), **options):
    """The StudyDef attributes the analysis reads (interface file), nothing else."""
    design = SimpleNamespace(
        points=points,
        factor_names=tuple(problem["names"]),
        grid_shape=None,
        salib_problem=problem,
        method=method,
        salib_options=options,
    )
    return SimpleNamespace(
        name="stub",
        kind="sensitivity",
        seed=19,
        metrics=tuple(SimpleNamespace(name=m, unit="m", long_name=m) for m in metrics),
        design=lambda: design,
        definition=lambda: {"kind": "sensitivity"},
    )


def dataset(problem, x: np.ndarray, **metrics: np.ndarray) -> xr.Dataset:
    n = len(x)
    data = {f: ("sample", x[:, j], {"unit": "m"}) for j, f in enumerate(problem["names"])}
    data |= {m: ("sample", y, {"unit": "m", "long_name": m}) for m, y in metrics.items()}
    data["status"] = ("sample", np.zeros(n, dtype=np.int8))
    data["error"] = ("sample", np.full(n, "", dtype=object))
    return xr.Dataset(data)


@pytest.fixture(scope="module")
def saltelli():
    from SALib.sample import sobol as sample

    problem = {"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-math.pi, math.pi]] * 3}
    x = sample.sample(problem, 1024, calc_second_order=True, seed=3)
    return problem, x


def test_sobol_indices_of_ishigami_match_the_closed_form(saltelli):
    problem, x = saltelli
    study = study_stub(problem, "sobol-saltelli", x, calc_second_order=True)
    res = analysis.sobol(dataset(problem, x, y=ishigami(x)), study)
    s1, st = ishigami_exact()
    got = res.sel(metric="y")
    assert np.all(np.abs(got.S1.values - s1) < 0.03), (got.S1.values, s1)
    assert np.all(np.abs(got.ST.values - st) < 0.03), (got.ST.values, st)
    # the confidence half-widths are real bootstrap widths that cover the error
    assert np.all(got.S1_conf.values > 0) and np.all(got.ST_conf.values > 0)
    assert np.all(np.abs(got.ST.values - st) < 3 * got.ST_conf.values)
    assert res.sizes["factor_b"] == 3 and int(got.blocks_used) == 1024
    assert [r["factor"] for r in analysis.ranked(res, "y")] == ["x1", "x2", "x3"]


def test_failed_samples_drop_their_blocks_and_are_listed(saltelli):
    problem, x = saltelli
    study = study_stub(problem, "sobol-saltelli", x, calc_second_order=True)
    ds = dataset(problem, x, y=ishigami(x))
    status = ds.status.values.copy()
    status[[5, 8 * 10 + 2, 8 * 10 + 3]] = 1  # blocks 0 and 10 of 8 samples each
    ds["status"] = ("sample", status)
    ds["y"] = ds.y.where(status == 0)
    res = analysis.sobol(ds, study)
    assert int(res.blocks_used.sel(metric="y")) == 1022 and res.attrs["blocks_total"] == 1024
    assert json.loads(res.attrs["failed_samples"]) == [5, 82, 83]
    s1, _ = ishigami_exact()
    assert np.all(np.abs(res.S1.sel(metric="y").values - s1) < 0.03)


def test_too_few_complete_blocks_refuse_naming_the_failed_samples(saltelli):
    problem, x = saltelli
    x = x[: 8 * 6]
    study = study_stub(problem, "sobol-saltelli", x, calc_second_order=True)
    ds = dataset(problem, x, y=ishigami(x))
    ds["status"] = ("sample", np.where(np.arange(len(x)) % 8 == 1, 1, 0).astype(np.int8))
    with pytest.raises(analysis.AnalysisError, match=r"0 of 6 blocks.*6 samples failed.*1, 9"):
        analysis.sobol(ds, study)


def test_a_metric_without_enough_values_is_refused_alone(saltelli):
    problem, x = saltelli
    study = study_stub(problem, "sobol-saltelli", x, ("y", "z"), calc_second_order=True)
    z = np.where(np.arange(len(x)) % 8 == 4, np.nan, x[:, 0])  # undefined in every block
    res = analysis.sobol(dataset(problem, x, y=ishigami(x), z=z), study)
    assert str(res.note.sel(metric="z").values).startswith("refused: metric 'z': 0 of 1024")
    assert np.isnan(res.ST.sel(metric="z").values).all()
    assert np.isfinite(res.ST.sel(metric="y").values).all()
    assert str(res.note.sel(metric="y").values) == ""


def test_only_the_declared_sensitivity_metrics_are_analysed(saltelli):
    problem, x = saltelli
    study = study_stub(problem, "sobol-saltelli", x, ("y", "z"), calc_second_order=True)
    study.source_text = '[study]\nkind = "sensitivity"\n[study.sensitivity]\nmetrics = ["z"]\n'
    res = analysis.sobol(dataset(problem, x, y=ishigami(x), z=x[:, 1]), study)
    assert list(res.metric.values) == ["z"]
    np.testing.assert_allclose(res.S1.sel(metric="z").values, [0, 1, 0], atol=0.03)


def test_incomplete_design_is_refused(saltelli):
    problem, x = saltelli
    study = study_stub(problem, "sobol-saltelli", x, calc_second_order=True)
    with pytest.raises(analysis.AnalysisError, match="not whole Saltelli blocks of 8"):
        analysis.sobol(dataset(problem, x[:-3], y=ishigami(x[:-3])), study)


def test_morris_mu_star_of_a_linear_model_is_coefficient_times_range():
    from SALib.sample import morris as sample

    bounds = [[0.0, 2.0], [10.0, 10.5], [-1.0, 1.0], [0.0, 100.0]]
    coef = np.array([3.0, -40.0, 0.0, 0.01])
    problem = {"num_vars": 4, "names": ["a", "b", "c", "d"], "bounds": bounds}
    x = sample.sample(problem, 20, num_levels=4, seed=5)
    y = x @ coef + 1.0
    study = study_stub(problem, "morris", x, num_levels=4)
    res = analysis.morris(dataset(problem, x, y=y), study).sel(metric="y")
    expected = np.abs(coef) * np.ptp(np.array(bounds), axis=1)
    np.testing.assert_allclose(res.mu_star.values, expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.mu.values, coef * np.ptp(np.array(bounds), axis=1), atol=1e-9)
    np.testing.assert_allclose(res.sigma.values, 0.0, atol=1e-9)  # linear: no interaction


def test_morris_refuses_factor_values_that_are_not_trajectories():
    from SALib.sample import morris as sample

    problem = {"num_vars": 2, "names": ["a", "b"], "bounds": [[0.0, 1.0]] * 2}
    x = sample.sample(problem, 6, num_levels=4, seed=1)
    shuffled = x[np.random.default_rng(0).permutation(len(x))]
    study = study_stub(problem, "morris", shuffled, num_levels=4)
    ds = dataset(problem, shuffled, y=shuffled.sum(axis=1))
    with pytest.raises(analysis.AnalysisError, match="factors change at once"):
        analysis.morris(ds, study)


def test_morris_leaves_out_failed_samples_with_infinite_factor_values():
    from SALib.sample import morris as sample

    bounds = [[0.0, 2.0], [10.0, 10.5]]
    problem = {"num_vars": 2, "names": ["a", "b"], "bounds": bounds}
    x = sample.sample(problem, 8, num_levels=4, seed=5)
    y = x @ np.array([3.0, -40.0])
    x[4, 1] = np.inf  # trajectory 1 (samples 3-5): a factor mapped to +-inf, the run failed
    study = study_stub(problem, "morris", x, num_levels=4)
    ds = dataset(problem, x, y=y)
    ds["status"] = ("sample", (np.arange(len(x)) == 4).astype(np.int8))
    res = analysis.morris(ds, study).sel(metric="y")
    assert int(res.blocks_used) == 7
    np.testing.assert_allclose(res.mu_star.values, [6.0, 20.0], rtol=1e-9)
    ds["status"] = ("sample", np.zeros(len(x), dtype=np.int8))
    with pytest.raises(analysis.AnalysisError, match="factor 'b' is not finite"):
        analysis.morris(ds, study)
