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
