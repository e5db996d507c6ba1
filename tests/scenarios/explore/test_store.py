"""The study store (scenarios/explore/store.py): made whole or not at all, one study per
store, chunk writes with status last, error texts read back exactly through xarray."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError
from sarcomere.scenarios.explore.store import (
    Column,
    StoreError,
    StudyStore,
    check_out_folder,
    definition_diff,
    estimated_bytes,
)

N, CHUNK = 10, 4


def make(path, definition=None, fingerprint="f1", series=False):
    return StudyStore.open_or_create(
        path,
        definition=definition or {"kind": "grid", "grid": {"load": [0, 1]}},
        fingerprint=fingerprint,
        factors=[(Column("load", "kg", "load"), np.linspace(0.0, 0.1, N))],
        metrics=[Column("stroke", "m", "stroke")],
        series=[Column("series_x", "m", "x")] if series else [],
        series_time=np.linspace(0.0, 1.0, 3) if series else None,
        chunk=CHUNK,
        attrs={"base": "step-50g", "seed": None},
    )


def result(start, stop, errors=None, series=False):
    idx = np.arange(start, stop)
    errors = errors or [""] * len(idx)
    return SimpleNamespace(
        indices=idx,
        metrics={"stroke": idx * 1e-3},
        series={"x": np.outer(idx, [1.0, 2.0, 3.0])} if series else {},
        status=np.array([0 if not e else 1 for e in errors], np.int8),
        error=errors,
    )


def test_a_new_store_has_every_sample_missing_and_the_factors_written(tmp_path):
    store = make(check_out_folder(tmp_path / "out"))
    assert store.missing_chunks() == [(0, 4), (4, 8), (8, 10)]
    ds = store.read()
    assert (ds.status.values == -1).all() and ds.status.dtype == np.int8
    np.testing.assert_array_equal(ds["load"].values, np.linspace(0.0, 0.1, N))
    assert np.isnan(ds.stroke.values).all() and ds.stroke.attrs["unit"] == "m"
    assert ds.attrs["fingerprint"] == "f1" and ds.attrs["base"] == "step-50g"
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["study.zarr"]  # no temporary


def test_error_texts_come_back_exactly(tmp_path):
    store = make(tmp_path / "study.zarr")
    texts = [
        "",
        "solver: CVODES flag -4 at t = 0.0123 s; state: p=1.2e+05\nsecond line ü",
        "x" * 5000,
        "",
    ]
    store.write_many([(0, result(0, 4, texts))])
    ds = store.read()
    assert list(ds.error.values[:4]) == texts
    assert list(ds.status.values[:4]) == [0, 1, 1, 0]
    assert list(ds.error.values[4:]) == [""] * 6


class _DiesAtStatus:
    """A status array whose process dies when its chunk is to be written."""

    def __setitem__(self, rows, values):
        raise KeyboardInterrupt


def test_a_write_killed_before_its_status_leaves_the_chunk_missing(tmp_path):
    store = make(tmp_path / "study.zarr", series=True)
    store.write_many([(4, result(4, 8, series=True))])
    store._arrays["status"] = _DiesAtStatus()
    with pytest.raises(KeyboardInterrupt):
        store.write_many([(0, result(0, 4, series=True))])
    again = StudyStore.open(tmp_path / "study.zarr")
    assert again.missing_chunks() == [(0, 4), (8, 10)]
    ds = again.read()
    assert ds.stroke.values[1] == 1e-3  # the values were written, the status was not
    np.testing.assert_array_equal(ds.series_x.values[5], [5.0, 10.0, 15.0])
    np.testing.assert_array_equal(ds.time.values, [0.0, 0.5, 1.0])


def test_only_whole_chunks_are_written(tmp_path):
    store = make(tmp_path / "study.zarr")
    with pytest.raises(StoreError, match="not the chunk"):
        store.write_many([(2, result(2, 6))])


def test_another_definition_is_refused_with_the_differences(tmp_path):
    make(tmp_path / "study.zarr")
    other = {"kind": "grid", "grid": {"load": [0, 2], "n": [1]}}
    with pytest.raises(StoreError, match=r"grid\.load\.1: 1 -> 2; grid\.n: \(absent\) -> \[1\]"):
        make(tmp_path / "study.zarr", other, "f2")
    assert make(tmp_path / "study.zarr").missing_chunks()  # the same study opens


def test_out_folders_that_hold_something_else_are_refused(tmp_path):
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(ParameterError, match=r"'--out'.*holds notes\.txt and no study\.zarr"):
        check_out_folder(tmp_path / "busy")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ParameterError, match="'--out'"):
        check_out_folder(tmp_path / "file")
    fake = tmp_path / "fake" / "study.zarr"
    fake.mkdir(parents=True)
    (fake / "data.bin").write_bytes(b"\0")
    with pytest.raises(StoreError, match="not a sarcomere study store"):
        make(check_out_folder(tmp_path / "fake"))


def test_a_temporary_store_left_by_a_killed_run_is_cleared(tmp_path):
    stale = tmp_path / "out" / ".study.zarr.999.tmp"
    stale.mkdir(parents=True)
    make(check_out_folder(tmp_path / "out"))
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["study.zarr"]


def test_size_estimate_and_diff_helpers():
    assert estimated_bytes(1000, 3, 2, 100) == 1000 * (8 * 105 + 9)
    assert definition_diff({"a": 1}, {"a": 1}) == []
    assert definition_diff({"a": [1, 2]}, {"a": [1]}) == ["a: [1, 2] -> [1]"]


def test_named_lists_are_compared_by_name_and_long_values_shortened():
    stored = {"factors": [{"name": "a", "v": 1}, {"name": "b", "v": 0}], "x": list(range(50))}
    given = {"factors": [{"name": "a", "v": 2}], "x": [0]}
    diff = definition_diff(stored, given)
    assert diff[:2] == ["factors.a.v: 1 -> 2", "factors.b: {'name': 'b', 'v': 0} -> (absent)"]
    assert diff[2].startswith("x: [0, 1, 2,") and diff[2].endswith("... -> [0]")
    assert len(diff[2]) < 80


def test_a_studys_series_carry_their_signals_units():
    """montecarlo-family keeps the length and the load thread's tension over time: the
    store's series variables get the model's units (they had none)."""
    from sarcomere.scenarios.explore.study import Study

    study = Study.from_file("montecarlo-family")
    layout = study._layout(study.definition.design(), None)
    units = {c.name: c.unit for c in layout["series"]}
    assert units == {"series_myofibril.length": "m", "series_myofibril.actin3.T": "N"}
