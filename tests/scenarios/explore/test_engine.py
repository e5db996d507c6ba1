"""The study engine (scenarios/explore/engine.py, study.py) on a stand-in study: batches
on an embedded LocalCluster written to the store, resumed, a sample that kills its worker
retried once then recorded with status 2, size caps and bad cluster addresses refused.

The stand-in (a tiny StudyDef and evaluator defined here, sent to the workers by value)
keeps these tests independent of the simulator; tests/scenarios/explore/test_resume.py
runs the packaged studies through the CLI.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

from sarcomere.dynamics.errors import ParameterError
from sarcomere.scenarios.explore.engine import (
    ClusterError,
    cluster_client,
    local_cluster,
    merge_results,
)
from sarcomere.scenarios.explore.store import StoreError
from sarcomere.scenarios.explore.study import Study

cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import tests


@dataclass(frozen=True)
class Factor:
    name: str
    unit: str


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    long_name: str


@dataclass(frozen=True)
class Design:
    points: np.ndarray
    factor_names: tuple
    grid_shape: tuple | None
    method: str
    salib_problem: dict | None = None


@dataclass(frozen=True)
class StandIn:
    """A grid over load [kg] x pressure [Pa]; metrics are closed forms of the point."""

    name: str = "standin"
    loads: tuple = (0.0, 0.02, 0.05)
    pressures: tuple = (0.0, 1e5, 2e5, 3e5)
    batch: int | None = 4
    max_samples: int = 100_000
    kill: tuple = ()  # sample indices whose evaluation kills the worker process
    kind: str = "grid"
    base: str = "step-50g"
    seed: int | None = None
    series: object = None
    factors: tuple = (Factor("load", "kg"), Factor("pressure", "Pa"))
    metrics: tuple = field(
        default=(Metric("stroke", "m", "stroke"), Metric("rise_time", "s", "rise time"))
    )

    def definition(self) -> dict:
        return {"loads": list(self.loads), "pressures": list(self.pressures), "kill": []}

    def fingerprint(self) -> str:
        text = json.dumps(self.definition(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def design(self) -> Design:
        grid = np.array([(m, p) for m in self.loads for p in self.pressures], dtype=float)
        shape = (len(self.loads), len(self.pressures))
        return Design(grid, ("load", "pressure"), shape, "grid")


@dataclass(frozen=True)
class Result:
    indices: np.ndarray
    metrics: dict
    series: dict
    series_time: None
    status: np.ndarray
    error: list


def closed_form(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    load, pressure = points.T
    return 1e-9 * pressure - 0.01 * load, 0.1 + load


def evaluate(study: StandIn, indices: np.ndarray, points: np.ndarray) -> Result:
    """Stand-in of evaluate.evaluate_batch: samples at pressure 0 'fail'."""
    if any(i in study.kill for i in indices):
        os._exit(3)
    np.testing.assert_array_equal(points, study.design().points[indices])
    stroke, rise = closed_form(points)
    failed = points[:, 1] == 0.0
    stroke[failed] = np.nan
    errors = ["domain: pressure 0 Pa lifts nothing" if f else "" for f in failed]
    return Result(
        np.asarray(indices),
        {"stroke": stroke, "rise_time": rise},
        {},
        None,
        failed.astype(np.int8),
        errors,
    )


@pytest.fixture(scope="module")
def cluster():
    """The engine's embedded cluster (2 workers), shared by this module's studies."""
    with local_cluster(2) as cluster:
        yield cluster.scheduler_address


def run(study: StandIn, out, scheduler=None, **kw):
    if "workers" not in kw:
        kw["scheduler"] = scheduler
    return Study(study).run(out, progress=False, evaluate=evaluate, outputs=False, **kw)


def test_a_grid_study_runs_into_the_store_and_comes_back_on_the_grid(tmp_path, cluster):
    ds = run(StandIn(), tmp_path / "out", cluster)
    assert ds.stroke.dims == ("load", "pressure")
    np.testing.assert_array_equal(ds.pressure.values, [0.0, 1e5, 2e5, 3e5])
    load, pressure = np.meshgrid(ds["load"].values, ds.pressure.values, indexing="ij")
    stroke, rise = closed_form(np.stack([load.ravel(), pressure.ravel()], axis=1))
    ok = pressure > 0
    np.testing.assert_array_equal(ds.stroke.values[ok], stroke.reshape(load.shape)[ok])
    np.testing.assert_array_equal(ds.rise_time.values, rise.reshape(load.shape))
    assert (ds.status.values == (~ok).astype(int)).all()
    assert np.isnan(ds.stroke.values[~ok]).all()  # NaN only where the status says failed
    assert set(ds.error.values[~ok]) == {"domain: pressure 0 Pa lifts nothing"}
    assert set(ds.error.values[ok]) == {""}
    assert ds.stroke.attrs["unit"] == "m" and ds["load"].attrs["unit"] == "kg"
    assert ds.attrs["fingerprint"] == StandIn().fingerprint()
    assert json.loads(ds.attrs["grid_factors"]) == ["load", "pressure"]


def test_a_rerun_computes_only_the_missing_chunks(tmp_path, cluster):
    from sarcomere.scenarios.explore.store import StudyStore

    out = tmp_path / "out"
    full = run(StandIn(), out, cluster)
    store = StudyStore.open(out / "study.zarr")
    assert store.missing_chunks() == []
    store._group["status"][4:8] = -1  # as if the run had stopped before this chunk
    assert store.missing_chunks() == [(4, 8)]
    # a re-run whose evaluator would kill any worker outside the missing chunk
    again = run(StandIn(kill=(0, 1, 2, 3, 8, 9, 10, 11)), out, cluster)
    assert again.identical(full)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_sample_that_kills_its_worker_is_retried_once_then_recorded(tmp_path, cluster):
    ds = run(StandIn(kill=(5,)), tmp_path / "out", cluster).stack(sample=("load", "pressure"))
    status = ds.status.values
    assert status[5] == 2 and "worker lost twice" in str(ds.error.values[5])
    assert np.isnan(ds.stroke.values[5])
    others = np.delete(np.arange(12), 5)  # the rest of its batch was saved by the retry
    assert set(status[others]) <= {0, 1}
    assert not np.isnan(ds.rise_time.values[others]).any()


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_different_definition_is_refused_naming_what_differs(tmp_path):
    run(StandIn(), tmp_path / "out", workers=1)  # the embedded cluster of Study.run
    with pytest.raises(StoreError, match=r"pressures\.3: 300000\.0 -> 400000\.0"):
        run(StandIn(pressures=(0.0, 1e5, 2e5, 4e5)), tmp_path / "out", workers=1)


def test_caps_are_checked_before_any_work(tmp_path):
    with pytest.raises(ParameterError, match=r"max_samples' = 10 .*>= 12"):
        run(StandIn(), tmp_path / "a", max_samples=10)
    with pytest.raises(ParameterError, match=r"max_store_bytes' = 100 .*12 samples"):
        run(StandIn(), tmp_path / "b", max_store_bytes=100)
    with pytest.raises(ParameterError, match=r"'--workers' = 0"):
        run(StandIn(), tmp_path / "c", workers=0)
    with pytest.raises(ParameterError, match=r"'--scheduler' = 'nohostport'"):
        run(StandIn(), tmp_path / "d", scheduler="nohostport")
    assert not any((tmp_path / x).exists() for x in "abcd")


def test_an_unreachable_scheduler_is_one_error_within_ten_seconds():
    import socket

    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(
        ClusterError, match=f"no Dask scheduler reachable at tcp://127.0.0.1:{port}"
    ):
        with cluster_client(scheduler=f"127.0.0.1:{port}"):
            pass
    assert time.perf_counter() - t0 < 10
    with pytest.raises(ParameterError, match="--scheduler"):
        with cluster_client(scheduler="tcp://nohostport"):
            pass


def test_merged_parts_keep_sample_order_and_nan_for_lost_samples():
    a = Result(
        np.array([2, 3]), {"x": np.array([1.0, 2.0])}, {}, None, np.zeros(2, np.int8), ["", ""]
    )
    lost = Result(np.array([1]), {}, {}, None, np.array([2], np.int8), ["lost"])
    merged = merge_results([a, lost])
    np.testing.assert_array_equal(merged.indices, [1, 2, 3])
    np.testing.assert_array_equal(merged.metrics["x"], [np.nan, 1.0, 2.0])
    assert merged.error == ["lost", "", ""] and list(merged.status) == [2, 0, 0]


_STUDY_HEAVY = ("dask", "distributed", "xarray", "zarr", "SALib", "casadi", "pandas")
_PROBE = f"""
import json, sys
from sarcomere.scenarios.cli import main
try:
    status = main(sys.argv[1:])
except SystemExit as exc:
    status = exc.code
print(json.dumps([status, sorted(m for m in {_STUDY_HEAVY!r} if m in sys.modules)]))
"""


@pytest.mark.parametrize(
    ("argv", "status"),
    [
        (["--help"], 0),
        (["list"], 0),
        (["study", "--help"], 0),
        (["study", "design-map"], 2),  # no --out
        (["study", "design-map", "--out", "x", "--workers", "0"], 2),
        (["study", "design-map", "--out", "x", "--workers", "2", "--scheduler", "h:1"], 2),
        (["run", "step-50g", "--bogus"], 2),
    ],
)
def test_the_cli_starts_without_the_study_libraries(argv, status):
    """Dask, xarray, Zarr and SALib load only when a study runs."""
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, *argv], capture_output=True, text=True, check=True
    )
    assert json.loads(done.stdout.splitlines()[-1]) == [status, []], done.stderr


def test_default_batches_keep_tasks_few_but_enough():
    from sarcomere.scenarios.explore.engine import default_batch

    assert [default_batch(n) for n in (1, 6, 48, 100, 1000, 100_000)] == [1, 1, 6, 13, 32, 64]


def test_a_task_that_cannot_import_on_the_worker_is_a_cluster_error(tmp_path, cluster):
    with pytest.raises(ClusterError, match="workers need the same Python environment"):
        Study(StandIn()).run(
            tmp_path / "out", scheduler=cluster, progress=False, evaluate=missing, outputs=False
        )


def missing(study, indices, points):
    """An evaluator whose module is not installed on the workers."""
    import sarcomere_not_installed  # noqa: F401


def test_the_cli_store_cap_refuses_before_any_work(tmp_path, capsys):
    """montecarlo-family keeps series: about 3.3 MB estimated, over a 1 MB cap."""
    from sarcomere.scenarios.cli import main

    out = tmp_path / "mc"
    status = main(["study", "montecarlo-family", "--out", str(out), "--max-store-mb", "1"])
    err = capsys.readouterr().err
    assert status != 0
    assert "max_store_bytes' = 1000000" in err and "3.3 MB" in err and "--max-store-mb" in err
    assert not out.exists()


def count_workers(study: StandIn, indices: np.ndarray, points: np.ndarray) -> Result:
    """The stand-in's result, each sample's note = the number of workers of the cluster."""
    from distributed import get_client

    result = evaluate(study, indices, points)
    n = len(get_client().scheduler_info()["workers"])
    return Result(*list(vars(result).values())[:-1], [f"workers={n}"] * len(indices))


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_workers_capped_at_the_tasks_with_a_warning_above_the_cpus(tmp_path, capfd, monkeypatch):
    """Issue 24, bug 5: --workers 64 on 2 cores started 64 processes for 4 samples."""
    from sarcomere.scenarios.explore import engine

    monkeypatch.setattr(engine, "default_workers", lambda: 1)
    ds = Study(StandIn()).run(  # 12 samples in 3 tasks of 4
        tmp_path / "out", workers=5, progress=False, evaluate=count_workers, outputs=False
    )
    assert set(ds.error.values.ravel()) == {"workers=3"}
    err = capfd.readouterr().err
    assert "warning: --workers 5 is above the 1 usable CPU: the workers share it" in err
    assert "3 started (the tasks to run)" in err and "Traceback" not in err


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_worker_death_prints_no_log_line(tmp_path):
    """Issue 24, bug 5: a raw 'distributed.scheduler - ERROR' line, even with --quiet (a
    process of its own: distributed's log handlers write to the stderr of their import)."""
    script = (
        f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import test_engine as t\n"
        "if __name__ == '__main__':\n"
        f"    ds = t.run(t.StandIn(kill=(5,)), {str(tmp_path / 'out')!r}, workers=2)\n"
        "    print(ds.status.values.ravel().tolist())\n"
    )
    (tmp_path / "death.py").write_text(script)
    done = subprocess.run(
        [sys.executable, str(tmp_path / "death.py")], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)[5] == 2
    assert "distributed" not in done.stderr and "Traceback" not in done.stderr, done.stderr


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_study_folder_in_use_is_refused_naming_the_process(tmp_path):
    """Issue 24, bug 4: two runs on one new --out, one died with FileNotFoundError (the
    other's clean-up removed its temporary store). One writer; the other is refused."""
    from sarcomere.scenarios.explore.store import locked

    out = tmp_path / "out"
    with locked(out):
        with pytest.raises(StoreError, match=f"{out} is in use by process {os.getpid()}"):
            run(StandIn(), out, workers=1)
        assert sorted(p.name for p in out.iterdir()) == [".study.lock"]
    assert run(StandIn(), out, workers=1).status.size == 12  # free again; the lock file stays


def test_a_server_that_is_not_dask_is_named_so(tmp_path):
    """Issue 24: a non-Dask port (one that greets, as SSH does) was reported as
    'MemoryError: Unable to allocate 3 EiB'."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def greet() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn, contextlib.suppress(OSError):  # the client hangs up
                conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
                conn.recv(1024)

    threading.Thread(target=greet, daemon=True).start()
    try:
        with pytest.raises(ClusterError, match=f"127.0.0.1:{port} answers but is not a Dask"):
            with cluster_client(scheduler=f"127.0.0.1:{port}"):
                pass
    finally:
        server.close()


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_progress_lines_when_the_output_is_not_a_terminal(tmp_path, capsys):
    """Issue 24: a batch job's log showed no progress (the line is for terminals only)."""
    Study(StandIn()).run(tmp_path / "out", workers=1, evaluate=evaluate, outputs=False)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("study standin: ")]
    assert [line.split(",")[0] for line in lines] == [
        "study standin: 4/12 samples",
        "study standin: 8/12 samples",
        "study standin: 12/12 samples",
    ]
    assert ", 3 failed, " in lines[-1] and "\r" not in err
