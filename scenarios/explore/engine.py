"""Running a study's batches on Dask (``dask.distributed``) into its store.

:func:`cluster_client` gives a client of an embedded ``LocalCluster`` (worker processes,
one thread and one BLAS thread each) or of an existing cluster (``--scheduler
tcp://HOST:PORT``; an unreachable one is a one-line error within :data:`CONNECT_TIMEOUT_S`).
:func:`run_chunks` submits one task per store chunk (a batch of samples), keeps a bounded
number in flight and writes each result to the store as it finishes (``as_completed``).

A task whose worker dies (crash, ``os._exit``, the nanny killing it past its memory limit)
is retried once, split into one task per sample so that the other samples of its batch are
saved; a sample whose retry kills its worker again is recorded with status 2 and a
message. The embedded cluster fails a task at its first worker death and gives each
worker one task at a time (so a dying worker takes no other task with it); an existing
cluster keeps its own policy (``distributed.scheduler.allowed-failures``, default 3
deaths before a task fails), before this retry. An exception raised by the evaluator
itself (not a sample's failure, which it records) stops the study: what was written
stays and a re-run resumes.
"""

from __future__ import annotations

import asyncio
import importlib.util
import logging
import math
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

from sarcomere.dynamics.errors import ParameterError, SarcomereError

from .store import WORKER_LOST, StudyStore

#: Seconds to reach an existing scheduler before giving up.
CONNECT_TIMEOUT_S = 5.0

#: Seconds to wait for the first worker of an existing cluster.
WORKER_WAIT_S = 30.0

#: Default batch [samples per task]: about TARGET_TASKS tasks, at least MIN_BATCH samples
#: each while the study has 8 tasks or more, at most MAX_BATCH (BENCHMARKS.md, design
#: studies: the scheduler's cost per task against a sample's).
TARGET_TASKS, MIN_BATCH, MAX_BATCH = 64, 32, 64

#: Environment of the embedded cluster's worker processes: one BLAS/OpenMP thread.
WORKER_ENV = {
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "BLIS_NUM_THREADS": "1",
    "SARCOMERE_BLAS_THREADS": "1",
}

#: Progress of a study whose output is not a terminal: a line every this many percent.
LOG_PERCENT = 5.0

Evaluate = Callable[..., object]
"""``evaluate(study, indices[, points]) -> BatchResult`` (see ``evaluate.evaluate_batch``;
``points`` are the batch's rows of the design, passed when the engine has them)."""


class ClusterError(SarcomereError):
    """The Dask cluster cannot be reached or has no workers."""


def default_batch(n_samples: int) -> int:
    """Samples per task when the study sets none (see :data:`TARGET_TASKS`)."""
    low = min(MIN_BATCH, math.ceil(n_samples / 8))
    return max(1, low, min(MAX_BATCH, math.ceil(n_samples / TARGET_TASKS)))


def default_workers() -> int:
    """Worker processes of the embedded cluster: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def embedded_workers(requested: int | None, tasks: int) -> tuple[int, str]:
    """Worker processes of the embedded cluster for ``tasks`` tasks: ``requested``
    (default: the usable CPUs) capped at the task count, and a warning (``""`` when none)
    when more are asked for than there are usable CPUs."""
    cores = default_workers()
    n = max(1, min(requested or cores, tasks))
    if requested is None or requested <= cores:
        return n, ""
    cap = f"; {n} started (the tasks to run)" if n < requested else ""
    cpus = (
        f"{cores} usable CPUs: the workers share them"
        if cores > 1
        else "1 usable CPU: the workers share it"
    )
    return n, f"warning: --workers {requested} is above the {cpus}{cap}"


@contextmanager
def _silent_distributed() -> Iterator[None]:
    """distributed's own log lines off (a worker lost, connections closed while the
    cluster shuts down): the engine reports a lost sample itself (status 2). In this
    process, and in the worker processes started meanwhile (they read the variable when
    they import distributed)."""
    logger = logging.getLogger("distributed")
    level, env = logger.level, os.environ.get(_LOG_VARIABLE)
    logger.setLevel(logging.CRITICAL + 1)
    os.environ[_LOG_VARIABLE] = "critical"
    try:
        yield
    finally:
        logger.setLevel(level)
        if env is None:
            os.environ.pop(_LOG_VARIABLE, None)
        else:
            os.environ[_LOG_VARIABLE] = env


_LOG_VARIABLE = "DASK_LOGGING__DISTRIBUTED"


def _scheduler_address(address: str) -> str:
    """``address`` with a scheme (``tcp://`` when none), checked for ``HOST:PORT``."""
    full = address if "://" in address else f"tcp://{address}"
    scheme, _, rest = full.partition("://")
    host, _, port = rest.rpartition(":")
    if scheme not in ("tcp", "tls", "ucx", "ws", "wss") or not host or not port.isdigit():
        raise ParameterError("--scheduler", address, "tcp://HOST:PORT (or HOST:PORT)")
    return full


def _probe(address: str) -> None:
    """Check that a Dask scheduler answers at ``address`` (raises otherwise): a refused
    TCP port fails at once, a silent one after :data:`CONNECT_TIMEOUT_S`, a server that is
    not a Dask scheduler on its first answer."""
    scheme, _, rest = address.partition("://")
    if scheme == "tcp":
        host, _, port = rest.rpartition(":")
        with socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT_S) as s:
            _check_greeting(s, address)
    from distributed.core import rpc

    async def identity() -> dict:
        remote = rpc(address, timeout=CONNECT_TIMEOUT_S)
        try:
            return await remote.identity()
        finally:
            await remote.close_rpc()

    def ask() -> dict:
        return asyncio.run(asyncio.wait_for(identity(), CONNECT_TIMEOUT_S))

    with ThreadPoolExecutor(1) as pool:  # its own event loop, also under a running one
        kind = pool.submit(ask).result().get("type")
    if kind != "Scheduler":
        raise OSError(f"the server there is a {kind}, not a Dask scheduler")


#: Largest first message of a Dask server (its handshake is about 60 bytes).
_GREETING_MAX_BYTES = 1 << 20


def _check_greeting(sock: socket.socket, address: str) -> None:
    """A Dask server speaks first: an 8-byte little-endian message length, then its
    handshake. A server that says something else is not one (its first bytes read as
    a length would ask for exabytes)."""
    sock.settimeout(CONNECT_TIMEOUT_S)
    try:
        head = sock.recv(8, socket.MSG_WAITALL)
    except TimeoutError:
        head = b""
    size = int.from_bytes(head, "little") if len(head) == 8 else 0
    if not 0 < size <= _GREETING_MAX_BYTES:
        said = repr(head[:16]) if head else "nothing"
        raise ClusterError(
            f"--scheduler: {address} answers but is not a Dask scheduler (it said {said} "
            f"within {CONNECT_TIMEOUT_S:.0f} s; a scheduler greets with its handshake)"
        )


def check_cluster_arguments(workers: int | None, scheduler: str | None) -> str | None:
    """Refuse bad ``workers``/``scheduler`` values (before any work); the scheduler's
    full address, or None for an embedded cluster."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)):
        raise ParameterError("--workers", workers, "a whole number >= 1")
    if workers is not None and workers < 1:
        raise ParameterError("--workers", workers, "a whole number >= 1")
    if scheduler is not None and workers is not None:
        raise ParameterError(
            "--workers", workers, "not with --scheduler (the cluster has its workers)"
        )
    return None if scheduler is None else _scheduler_address(scheduler)


@contextmanager
def cluster_client(
    workers: int | None = None, scheduler: str | None = None, *, stream: TextIO | None = None
) -> Iterator[object]:
    """A ``distributed.Client``: of an embedded ``LocalCluster`` with ``workers`` processes
    (default :func:`default_workers`), or of the running cluster at ``scheduler``. The
    dashboard's address is printed on ``stream`` when there is one."""
    address = check_cluster_arguments(workers, scheduler)
    with _silent_distributed():
        with _client(address, workers, stream) as client:
            yield client


@contextmanager
def _client(address: str | None, workers: int | None, stream: TextIO | None):
    from distributed import Client

    cluster = None
    if address is None:
        cluster = local_cluster(workers or default_workers())
        client = Client(cluster, set_as_default=False)
    else:
        try:
            _probe(address)  # a refused port fails at once, not after the timeout
            client = Client(address, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False)
        except ClusterError:
            raise
        except Exception as exc:  # refused, timed out, or not speaking Dask's protocol
            reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:160]
            raise ClusterError(
                f"--scheduler: no Dask scheduler reachable at {address} within "
                f"{CONNECT_TIMEOUT_S:.0f} s ({reason})"
            ) from None
    try:
        if address is not None:
            _wait_for_a_worker(client, address)
        _print_dashboard(client, stream, local=cluster is not None)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while worker processes start, so they inherit that: Ctrl-C at a
    terminal (sent to the whole process group) then stops the study in this process
    alone, which closes the cluster, instead of a traceback from every worker."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def local_cluster(workers: int):
    """An embedded ``distributed.LocalCluster``: ``workers`` processes of one thread and
    one BLAS thread each, no dashboard port fixed (one is chosen when bokeh is there).

    A worker that dies fails its task at once (:func:`run_chunks` does the one retry),
    and only that task: a worker is given one task at a time, so none waits on it.
    """
    import dask
    from distributed import LocalCluster

    config = {
        "distributed.scheduler.allowed-failures": 0,
        "distributed.scheduler.worker-saturation": 1.0,
        "distributed.worker.profile.enabled": False,  # its sampling thread: ~6 % of a sample
    }
    with dask.config.set(config), _sigint_ignored():
        try:
            return LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=logging.CRITICAL + 1,  # the workers' log lines too
                env=WORKER_ENV,
            )
        except RuntimeError as exc:  # "Nanny failed to start."
            raise ClusterError(
                f"the embedded Dask cluster's workers did not start ({exc}); a script that "
                'runs a study must run it under if __name__ == "__main__": (each worker '
                "process imports the script again; see docs/studies.md)"
            ) from None


def _wait_for_a_worker(client, address: str) -> None:
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:
        raise ClusterError(
            f"--scheduler: the cluster at {address} has no worker after {WORKER_WAIT_S:.0f} s"
        ) from None


def _print_dashboard(client, stream: TextIO | None, local: bool) -> None:
    """Print the dashboard's address when the scheduler serves one (an embedded cluster
    serves its pages only with bokeh installed)."""
    if stream is None or (local and importlib.util.find_spec("bokeh") is None):
        return
    if "dashboard" in client.scheduler_info().get("services", {}):
        print(f"Dask dashboard: {client.dashboard_link}", file=stream, flush=True)


@dataclass
class _Job:
    """A chunk of the store and the results of its parts so far."""

    start: int
    stop: int
    parts: list = field(default_factory=list)
    waiting: int = 1


@dataclass(frozen=True)
class _Lost:
    """The result of samples whose worker died twice."""

    indices: np.ndarray
    status: np.ndarray
    error: list[str]
    metrics: dict = field(default_factory=dict)
    series: dict = field(default_factory=dict)
    series_time: np.ndarray | None = None


def _lost(indices: np.ndarray, reason: str) -> _Lost:
    message = (
        f"worker lost twice running this sample ({reason}): it crashed, exited or exceeded "
        "its memory limit"
    )
    return _Lost(
        indices=indices,
        status=np.full(len(indices), WORKER_LOST, np.int8),
        error=[message] * len(indices),
    )


def merge_results(parts: Sequence[object]) -> _Lost:
    """One result from several covering consecutive samples (in index order); a metric or
    series missing from a part (a lost sample) is NaN there."""
    parts = sorted(parts, key=lambda p: int(np.asarray(p.indices)[0]))
    sizes = [len(p.indices) for p in parts]
    metrics = {}
    for name in {n for p in parts for n in p.metrics}:
        metrics[name] = np.concatenate(
            [
                np.asarray(p.metrics.get(name, np.full(s, np.nan)))
                for p, s in zip(parts, sizes, strict=True)
            ]
        )
    series = {}
    for name in {n for p in parts for n in (p.series or {})}:
        width = next(np.asarray(p.series[name]).shape[1] for p in parts if name in p.series)
        series[name] = np.concatenate(
            [
                np.asarray(p.series[name]) if name in p.series else np.full((s, width), np.nan)
                for p, s in zip(parts, sizes, strict=True)
            ]
        )
    return _Lost(
        indices=np.concatenate([np.asarray(p.indices) for p in parts]),
        status=np.concatenate([np.asarray(p.status, np.int8) for p in parts]),
        error=[e for p in parts for e in p.error],
        metrics=metrics,
        series=series,
    )


class Progress:
    """Samples done of total, failures, rate and time left, for a progress line."""

    def __init__(self, total: int, done: int, failed: int) -> None:
        self.total, self.done, self.failed = total, done, failed
        self._start_done, self._t0 = done, time.perf_counter()
        self._mark = -1

    def add(self, status: np.ndarray) -> None:
        self.done += len(status)
        self.failed += int(np.count_nonzero(status != 0))

    def step(self, percent: float) -> bool:
        """True when the samples done have passed another multiple of ``percent`` % of the
        total since the last True (or reached the total)."""
        mark = int(100 * self.done / (percent * self.total)) if self.total else 0
        passed = mark > self._mark or self.done == self.total
        self._mark = mark
        return passed

    def text(self) -> str:
        """E.g. ``"120/400 samples, 2 failed, 3.1 /s, 90 s left"``."""
        elapsed = time.perf_counter() - self._t0
        rate = (self.done - self._start_done) / elapsed if elapsed > 0 else 0.0
        left = f", {(self.total - self.done) / rate:.0f} s left" if rate > 0 else ""
        return f"{self.done}/{self.total} samples, {self.failed} failed, {rate:.3g} /s{left}"


def _task_error(exc: BaseException, indices: np.ndarray) -> BaseException:
    """What a task's own exception (not one sample's failure, which the evaluator
    records) becomes: a SarcomereError as it was, a missing module on the workers a
    ClusterError saying so, anything else unchanged (a bug: its traceback is wanted)."""
    if isinstance(exc, SarcomereError):
        return exc
    if isinstance(exc, ImportError):
        return ClusterError(
            f"a task (samples {indices[0]}-{indices[-1]}) failed on a worker: "
            f"{type(exc).__name__}: {exc}; the workers need the same Python environment "
            "(sarcomere and its dependencies installed) as this process"
        )
    return exc


def run_chunks(
    client,
    evaluate: Evaluate,
    study: object,
    store: StudyStore,
    chunks: Sequence[tuple[int, int]],
    *,
    on_result: Callable[[object], None] | None = None,
    max_in_flight: int | None = None,
    points: np.ndarray | None = None,
) -> None:
    """Evaluate the ``chunks`` ((start, stop) sample ranges) of ``store`` on ``client``'s
    cluster and write each as it finishes. With the design's ``points`` (samples x
    factors), each task gets its rows and the workers need not make the design.

    Results are fetched in the background as tasks complete; all those that completed
    together are written in one go. ``on_result(result)`` is called with each chunk's
    result once it is written. At most ``max_in_flight`` tasks are queued at once
    (default: four per worker thread, at least 8) so memory stays flat over any study.
    """
    from distributed import KilledWorker, as_completed

    if max_in_flight is None:
        threads = sum(client.nthreads().values()) or 1
        max_in_flight = max(8, 4 * threads)
    todo = iter(chunks)
    futures = as_completed(loop=client.loop, with_results=True, raise_errors=False)
    owner: dict = {}

    def submit(job: _Job, indices: np.ndarray, attempt: int) -> None:
        if points is None:
            future = client.submit(evaluate, study, indices, pure=False)
        else:
            future = client.submit(evaluate, study, indices, points[indices], pure=False)
        owner[future] = (job, indices, attempt)
        futures.add(future)

    def refill() -> None:
        while futures.count() < max_in_flight:
            chunk = next(todo, None)
            if chunk is None:
                return
            job = _Job(*chunk)
            submit(job, np.arange(job.start, job.stop), 0)

    def complete(job: _Job, part: object, done: list) -> None:
        job.parts.append(part)
        job.waiting -= 1
        if job.waiting == 0:
            done.append(
                (job.start, job.parts[0] if len(job.parts) == 1 else merge_results(job.parts))
            )

    try:
        refill()
        for batch in futures.batches():
            done: list = []
            for future, value in batch:
                job, indices, attempt = owner.pop(future)
                if future.status == "error":  # value = (type, exception, traceback)
                    value = value[1]
                future.release()
                if not isinstance(value, BaseException):
                    complete(job, value, done)
                elif "Cancelled" in type(value).__name__:  # its data lost: compute again
                    submit(job, indices, attempt)
                elif not isinstance(value, KilledWorker):
                    raise _task_error(value, indices) from value
                elif attempt == 0:  # retry once, one task per sample
                    job.waiting += len(indices) - 1
                    for i in indices:
                        submit(job, np.array([i]), 1)
                else:
                    complete(job, _lost(indices, type(value).__name__), done)
            refill()  # the workers get going while the results are written
            store.write_many(done)
            for _, result in done:
                if on_result is not None:
                    on_result(result)
    finally:
        for future in list(owner):
            future.cancel()


def run_study(
    evaluate: Evaluate,
    study: object,
    store: StudyStore,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    stream: TextIO | None = None,
    points: np.ndarray | None = None,
) -> None:
    """Compute every chunk of ``store`` not yet computed, on a cluster made or reached
    by :func:`cluster_client`, with a progress line on terminals (elsewhere, a line every
    :data:`LOG_PERCENT` % of the samples)."""
    from ..progress import progress as progress_line
    from ..progress import report

    chunks = store.missing_chunks()
    if not chunks:
        return
    out = sys.stderr if stream is None else stream
    status = store.status()
    counter = Progress(
        store.n_samples,
        int(np.count_nonzero(status >= 0)),
        int(np.count_nonzero(status > 0)),
    )
    label = f"study {getattr(study, 'name', '')}".rstrip()
    if scheduler is None:
        workers, warning = embedded_workers(workers, len(chunks))
        if warning:
            print(warning, file=out, flush=True)

    lines = progress and not out.isatty()  # a batch job's log: a line every few percent

    def on_result(result) -> None:
        counter.add(np.asarray(result.status))
        report(counter.text())
        if lines and counter.step(LOG_PERCENT):
            print(f"{label}: {counter.text()}", file=out, flush=True)

    with cluster_client(workers, scheduler, stream=out if progress else None) as client:
        with progress_line(label, enabled=progress, stream=out, delay=0.5):
            report(counter.text())
            run_chunks(client, evaluate, study, store, chunks, on_result=on_result, points=points)
