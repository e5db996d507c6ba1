"""Each figure kind drawn from a small synthetic study Dataset (the interface file's
layout), ``summary.json``'s numbers checked against numpy on the same data, and failed
samples left out and counted."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

xr = pytest.importorskip("xarray")
pytest.importorskip("SALib")

from sarcomere.scenarios.explore import outputs, plots  # noqa: E402

LOADS = np.array([0.0, 0.02, 0.05, 0.1])  # kg
PRESSURES = np.linspace(0.0, 0.3e6, 7)  # Pa
NS = np.array([1.0, 2.0, 3.0])


def stub(kind, factors, metrics, method, problem=None, **options):
    """The StudyDef attributes the outputs read (interface file), nothing else."""
    design = SimpleNamespace(method=method, salib_problem=problem, salib_options=options)
    return SimpleNamespace(
        name=f"synthetic-{kind}",
        base="step-50g",
        fidelity="full",
        kind=kind,
        seed=19,
        factors=tuple(
            SimpleNamespace(name=n, unit=u, kind="discrete" if v else "continuous", values=v)
            for n, u, *rest in factors
            for v in [tuple(rest[0]) if rest else ()]
        ),
        metrics=tuple(SimpleNamespace(name=n, unit=u, long_name=n) for n, u in metrics),
        design=lambda: design,
        definition=lambda: {"kind": kind},
        fingerprint=lambda: "f" * 64,
        scene=lambda: SimpleNamespace(parameter_sources=dict),  # no parameter file
    )


def stroke(load, pressure, n):
    """A made-up smooth stroke [m]: grows with pressure and n, falls with load."""
    return 0.01 * n * (pressure / 0.3e6) ** 0.8 / (1.0 + 20.0 * load)


@pytest.fixture
def grid():
    load, p, n = np.meshgrid(LOADS, PRESSURES, NS, indexing="ij")
    status = np.zeros(load.shape, dtype=np.int8)
    status[1, 3, 2] = 1  # one solver failure
    error = np.where(status == 1, "SolverError: step size too small at t = 0.31 s", "")
    s = np.where(status == 0, stroke(load, p, n), np.nan)
    rise = np.where(p > 0, 0.05 + 0.1 * load, np.nan)  # no rise time without a stroke
    error[(p == 0) & (status == 0)] = "rise_time: the stroke is below the noise level"
    rise[status != 0] = np.nan
    dims = ("load", "pressure", "n")
    t = np.linspace(0.0, 2.0, 51)
    length = 0.165 - s[..., None] * (1 - np.exp(-t / (0.05 + 0.1 * load[..., None])))
    ds = xr.Dataset(
        {
            "stroke": (dims, s, {"unit": "m", "long_name": "stroke"}),
            "rise_time": (dims, rise, {"unit": "s"}),
            "series_myofibril.length": ((*dims, "time"), length, {"unit": "m"}),
            "status": (dims, status),
            "error": (dims, error.astype(object)),
        },
        coords={
            "load": ("load", LOADS, {"unit": "kg"}),
            "pressure": ("pressure", PRESSURES, {"unit": "Pa"}),
            "n": ("n", NS, {"unit": "1"}),
            "time": ("time", t, {"unit": "s"}),
        },
        attrs={"fingerprint": "a" * 64, "version": "0.1.0", "method": "grid"},
    )
    study = stub(
        "grid",
        [("load", "kg"), ("pressure", "Pa"), ("n", "1")],
        [("stroke", "m"), ("rise_time", "s")],
        "grid",
    )
    return ds, study


@pytest.fixture
def montecarlo():
    rng = np.random.default_rng(4)
    count, t = 40, np.linspace(0.0, 2.0, 101)
    area = rng.uniform(0.9, 1.1, count) * 2e-4  # m^2
    k = rng.normal(1.0, 0.05, count) * 300.0  # N/m
    family = np.array([4e-3, 8e-3, 16e-3])[np.arange(count) % 3]  # m, a discrete factor
    gain = area / 2e-4 * k / 300.0 * (1 + family)
    length = 0.165 - 0.02 * gain[:, None] * (1 - np.exp(-t[None, :] / 0.1))
    status = np.zeros(count, dtype=np.int8)
    status[[3, 17]] = 1
    status[25] = 2
    length[status != 0] = np.nan
    s = np.where(status == 0, 0.02 * gain, np.nan)
    ds = xr.Dataset(
        {
            "aps.A_p": ("sample", area, {"unit": "m^2"}),
            "thread.k": ("sample", k, {"unit": "N/m"}),
            "family": ("sample", family, {"unit": "m"}),
            "peak_pressure": ("sample", np.full(count, 1e5), {"unit": "Pa"}),  # constant
            "stroke": ("sample", s, {"unit": "m"}),
            "series_myofibril.length": (("sample", "time"), length, {"unit": "m"}),
            "status": ("sample", status),
            "error": ("sample", np.array(["" if v == 0 else "boom" for v in status], object)),
        },
        coords={"time": ("time", t, {"unit": "s"})},
        attrs={"fingerprint": "b" * 64, "version": "0.1.0", "method": "montecarlo"},
    )
    study = stub(
        "sample",
        [("aps.A_p", "m^2"), ("thread.k", "N/m"), ("family", "m", (4e-3, 8e-3, 16e-3))],
        [("stroke", "m"), ("peak_pressure", "Pa")],
        "montecarlo",
    )
    return ds, study


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_grid_outputs_draw_maps_and_summarise_with_factor_values(grid, tmp_path, drawn_png):
    ds, study = grid
    summary = outputs.write_outputs(ds, study, tmp_path)
    assert summary == json.loads((tmp_path / "summary.json").read_text())
    assert sorted(summary["plots"]) == [
        "curves_myofibril.length.png",
        "map_rise_time.png",
        "map_stroke.png",
    ]
    for name in summary["plots"]:
        drawn_png(tmp_path / name)
    samples = summary["samples"]
    assert (samples["total"], samples["ok"], samples["failed"]) == (84, 83, 1)
    assert samples["failures"][0]["at"] == {"load": 0.02, "pressure": 0.15e6, "n": 3.0}
    assert samples["errors"] == [
        {
            "message": "SolverError: step size too small at t = # s",
            "count": 1,
            "example": "SolverError: step size too small at t = 0.31 s",
            "samples": [32],
        }
    ]
    s = summary["metrics"]["stroke"]
    ok = ds.stroke.values[ds.status.values == 0]
    assert s["unit"] == "m" and s["count"] == 83
    assert s["median"] == pytest.approx(np.median(ok))
    assert s["p95"] == pytest.approx(np.percentile(ok, 95))
    assert s["max"]["value"] == pytest.approx(stroke(0.0, 0.3e6, 3.0))
    assert s["max"]["at"] == {"load": 0.0, "pressure": 0.3e6, "n": 3.0}
    assert s["min"]["value"] == 0.0 and s["min"]["at"]["pressure"] == 0.0
    assert summary["fingerprint"] == "a" * 64 and summary["version"] == "0.1.0"
    assert "1 of 84 samples are not ok" in summary["warnings"][0]
    rise = summary["metrics"]["rise_time"]
    assert (rise["count"], rise["undefined"], s["undefined"]) == (71, 12, 0)
    assert [(n["message"], n["count"]) for n in samples["notes"]] == [
        ("rise_time: the stroke is below the noise level", 12)
    ]
    note = plots.status_note(ds, "rise_time")
    assert note == "83 of 84 samples ok, 1 failed or missing (left out); rise_time undefined in 12"


def test_failures_of_one_kind_are_one_entry_with_count_and_example_samples(grid):
    """Issue 24: 12 failures of one kind were listed as 12 distinct messages."""
    ds, study = grid
    status, error = ds.status.values.copy(), ds.error.values.copy()
    for k, (i, j) in enumerate([(0, 1), (0, 2), (2, 4)]):
        status[i, j, 0] = 1
        error[i, j, 0] = f"SolverError: step size too small at t = {k + 4}.2e-1 s"
    status[3, 6, 1], error[3, 6, 1] = 1, "ParameterError: 'aps.k_s' = -1 is invalid"
    ds = ds.assign(status=(ds.status.dims, status), error=(ds.error.dims, error))
    errors = outputs.sample_counts(ds, study)["errors"]
    assert [(e["message"], e["count"], e["samples"]) for e in errors] == [
        ("SolverError: step size too small at t = # s", 4, [3, 6, 32, 54]),
        ("ParameterError: 'aps.k_s' = # is invalid", 1, [82]),
    ]
    assert errors[0]["example"] == "SolverError: step size too small at t = 4.2e-1 s"


def test_outputs_of_unchanged_results_are_not_drawn_again(grid, tmp_path, monkeypatch):
    """Issue 24: every resume of a finished study redrew every figure."""
    ds, study = grid
    ds = ds.isel(n=[2], load=[0, 3]).drop_vars("series_myofibril.length")
    first = outputs.write_outputs(ds, study, tmp_path)
    stamps = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    drawn = []
    monkeypatch.setattr(plots, "design_map", lambda *args: drawn.append(args[2]))
    assert outputs.write_outputs(ds, study, tmp_path) == first
    assert drawn == [] and stamps == {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    outputs.write_outputs(ds, study, tmp_path, force=True)  # --plots-only
    assert drawn == ["stroke", "rise_time"]
    changed = ds.assign(stroke=ds.stroke * 1.01)
    assert outputs.write_outputs(changed, study, tmp_path)["results"] != first["results"]
    assert drawn == ["stroke", "rise_time"] * 2


def test_without_plots_the_summary_alone_and_no_stale_figure(grid, tmp_path):
    ds, study = grid
    ds = ds.isel(n=[2], load=[0, 3]).drop_vars("series_myofibril.length")
    outputs.write_outputs(ds, study, tmp_path)
    summary = outputs.write_outputs(ds, study, tmp_path, draw=False)  # --no-plots
    assert summary["plots"] == [] and summary["metrics"]["stroke"]["count"] == 14
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


def test_rewriting_replaces_the_figures_of_the_previous_summary(grid, tmp_path):
    ds, study = grid
    ds = ds.isel(n=[2], load=[0, 3])  # a 2 x 7 map: fewer panels to draw
    outputs.write_outputs(ds, study, tmp_path)
    (tmp_path / "mine.png").write_bytes(b"not ours")
    summary = outputs.write_outputs(ds.drop_vars("rise_time"), study, tmp_path)
    assert summary["plots"] == ["map_stroke.png", "curves_myofibril.length.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "curves_myofibril.length.png",
        "map_stroke.png",
        "mine.png",
        "summary.json",
    ]


def test_a_metric_without_values_is_named_not_drawn(grid, tmp_path):
    ds, study = grid
    ds["stroke"] = ds.stroke * np.nan
    summary = outputs.write_outputs(ds.drop_vars("series_myofibril.length"), study, tmp_path)
    assert summary["plots"] == ["map_rise_time.png"]
    assert "no map of stroke" in summary["warnings"][-1]
    assert summary["metrics"]["stroke"]["median"] is None


def test_design_map_axes_facets_and_paper_points(grid):
    ds, _ = grid
    x, y, facet, fixed = plots._map_axes(ds.stroke)
    assert (x, y, facet, fixed) == ("pressure", "load", "n", {})
    concentric = plots.paper_points()[0][2]
    assert len(concentric) == 55 and {"n": 3.0, "load": 0.05, "pressure": 0.1e6} in concentric
    assert plots.status_note(ds) == "83 of 84 samples ok, 1 failed or missing (left out)"


def test_a_fourth_grid_axis_is_fixed_at_its_middle_level():
    da = xr.DataArray(
        np.zeros((5, 3, 4, 2)),
        dims=("n", "aps.k_s", "pressure", "load"),
        coords={
            "n": [1, 2, 3, 4, 5],
            "aps.k_s": [0.9, 1.0, 1.1],
            "pressure": [1, 2, 3, 4],
            "load": [0.0, 0.05],
        },
    )
    assert plots._map_axes(da) == ("pressure", "aps.k_s", "load", {"n": 3})


def test_single_axis_grid_draws_a_line(grid, tmp_path, drawn_png):
    ds, study = grid
    one = ds.isel(load=[0], n=[0])
    path = plots.design_map(one, study, "stroke", tmp_path) or plots.design_line(
        one, study, "stroke", tmp_path
    )
    drawn_png(path)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_montecarlo_envelope_and_histograms(montecarlo, tmp_path, drawn_png):
    ds, study = montecarlo
    summary = outputs.write_outputs(ds, study, tmp_path)
    assert sorted(summary["plots"]) == ["envelope_myofibril.length.png", "histograms.png"]
    for name in summary["plots"]:
        drawn_png(tmp_path / name)
    samples = summary["samples"]
    assert (samples["ok"], samples["failed"], samples["worker_lost"]) == (37, 2, 1)
    assert [f["sample"] for f in samples["failures"]] == [3, 17, 25]
    final = ds["series_myofibril.length"].values[ds.status.values == 0, -1]
    band = summary["series"]["myofibril.length"]["final"]
    assert band["median"] == pytest.approx(np.median(final))
    assert band["p05"] == pytest.approx(np.percentile(final, 5))
    s = summary["metrics"]["stroke"]
    i = int(np.nanargmax(ds.stroke.values))
    assert s["max"]["sample"] == i
    assert s["max"]["at"] == {
        "aps.A_p": ds["aps.A_p"].values[i],
        "thread.k": ds["thread.k"].values[i],
        "family": ds["family"].values[i],
    }
    assert plots._grouping(ds, study) == "family"
    p = summary["metrics"]["peak_pressure"]
    assert p["median"] == p["min"]["value"] == p["max"]["value"] == 1e5 and p["count"] == 37


def _sensitivity(method, tmp_path):
    from SALib.sample import morris as morris_sample
    from SALib.sample import sobol as sobol_sample

    problem = {"num_vars": 3, "names": ["a", "b", "c"], "bounds": [[0.0, 1.0]] * 3}
    if method == "sobol":
        x = sobol_sample.sample(problem, 64, calc_second_order=False, seed=2)
        options = {"calc_second_order": False}
    else:
        x = morris_sample.sample(problem, 12, num_levels=4, seed=2)
        options = {"num_levels": 4}
    y = 2.0 * x[:, 0] + np.sin(3 * x[:, 1]) * 0.5 + 0.01 * x[:, 2]
    status = np.zeros(len(x), dtype=np.int8)
    status[2] = 1
    data = {f: ("sample", x[:, j], {"unit": "m"}) for j, f in enumerate(problem["names"])}
    data |= {
        "stroke": ("sample", np.where(status == 0, y * 1e-3, np.nan), {"unit": "m"}),
        "status": ("sample", status),
        "error": ("sample", np.array(["" if s == 0 else "x" for s in status], object)),
    }
    ds = xr.Dataset(data, attrs={"fingerprint": "c" * 64, "version": "0.1.0"})
    study = stub(
        "sensitivity",
        [(f, "m") for f in problem["names"]],
        [("stroke", "m")],
        "sobol-saltelli" if method == "sobol" else "morris",
        problem,
        **options,
    )
    return outputs.write_outputs(ds, study, tmp_path)


@pytest.mark.parametrize("method", ["sobol", "morris"])
def test_sensitivity_outputs_rank_the_factors(method, tmp_path, drawn_png):
    summary = _sensitivity(method, tmp_path)
    assert summary["plots"] == [f"{method}.png"]
    drawn_png(tmp_path / f"{method}.png")
    sens = summary["sensitivity"]
    assert sens["method"] == method and sens["failed_samples"] == [2]
    stroke_ = sens["metrics"]["stroke"]
    assert stroke_["blocks_used"] == sens["blocks_total"] - 1
    assert [r["factor"] for r in stroke_["ranked"]] == ["a", "b", "c"]
    if method == "morris":
        assert stroke_["ranked"][0]["mu_star"] == pytest.approx(2e-3)  # linear in a: 2 mm/m x 1 m


def test_refused_analysis_is_reported_not_silent(tmp_path, monkeypatch):
    monkeypatch.setattr("sarcomere.scenarios.explore.analysis.MIN_BLOCKS", 10_000)
    summary = _sensitivity("sobol", tmp_path)
    assert "blocks of 5 samples are complete" in summary["sensitivity"]["refused"]
    assert any("refused" in w for w in summary["warnings"])
    assert summary["plots"] == []
