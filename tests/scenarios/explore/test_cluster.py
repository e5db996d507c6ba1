"""A study on a real Dask cluster over the loopback address: a ``dask scheduler`` and two
``dask worker`` processes (random free ports), the study run through ``--scheduler``
gives the same Dataset as the embedded LocalCluster."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

DASK = Path(sys.executable).parent / "dask"
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def _wait_for(path: Path, timeout: float = 30.0) -> dict:
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            time.sleep(0.1)
    raise TimeoutError(f"no scheduler file {path} after {timeout} s")


@pytest.fixture(scope="module")
def loopback_cluster(tmp_path_factory):
    """Address of a scheduler with two single-threaded workers on 127.0.0.1."""
    tmp = tmp_path_factory.mktemp("cluster")
    file = tmp / "scheduler.json"
    common = dict(cwd=tmp, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [
        subprocess.Popen(
            [
                DASK,
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                file,
            ],
            start_new_session=True,
            **common,
        )
    ]
    try:
        address = _wait_for(file)["address"]
        for name in ("w1", "w2"):
            procs.append(
                subprocess.Popen(
                    [
                        DASK,
                        "worker",
                        address,
                        "--nthreads",
                        "1",
                        "--name",
                        name,
                        "--host",
                        "127.0.0.1",
                        "--no-dashboard",
                        "--local-directory",
                        tmp / name,
                    ],
                    start_new_session=True,
                    **common,
                )
            )
        from distributed import Client

        with Client(address, timeout="20s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for proc in reversed(procs):
            os.killpg(proc.pid, signal.SIGTERM)
        for proc in procs:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


STUDY = """
[study]
kind = "grid"
base = "step-50g"
batch = 2
[study.grid]
load = ["20 g", "50 g", "80 g"]
pressure = ["0.05 MPa", "0.1 MPa"]
[study.metrics]
names = ["stroke", "rise_time", "peak_tension", "air_mass"]
[model]
n = 2
[simulation]
stop_time = "0.3 s"
"""


def study_cli(*args) -> list[str]:
    return [sys.executable, "-m", "sarcomere.scenarios.cli", "study", *map(str, args)]


@pytest.mark.slow  # a scheduler, two workers and two studies
def test_a_study_through_scheduler_equals_the_local_run(loopback_cluster, tmp_path):
    import xarray as xr

    study = tmp_path / "cluster.toml"
    study.write_text(STUDY)
    remote = subprocess.run(
        study_cli(study, "--out", tmp_path / "remote", "--scheduler", loopback_cluster),
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert remote.returncode == 0, remote.stderr
    assert "6 samples, 0 failed" in remote.stdout
    local = tmp_path / "local"
    subprocess.run(study_cli(study, "--out", local, "--quiet"), env=ENV, check=True, timeout=300)
    got = xr.open_zarr(tmp_path / "remote" / "study.zarr").load()
    ref = xr.open_zarr(local / "study.zarr").load()
    assert (ref.status.values == 0).all() and np.isfinite(ref.stroke.values).all()
    for ds in (got, ref):
        ds.attrs.pop("created")
    xr.testing.assert_identical(got, ref)
