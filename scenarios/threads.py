"""BLAS/LAPACK thread pools for the command line.

The models here are small (tens to a few hundred states): a multi-threaded BLAS only adds
synchronisation, and on a machine whose cores are busy it stalls. Measured on the 2-core
CI-class machine with the other core loaded: scipy ``expm`` of a 20 x 20 matrix took
1.6-8.8 ms with OpenBLAS's default threads and 0.036 ms with one (BENCHMARKS.md s6).
The CLI therefore runs every command with the pools limited to ``SARCOMERE_BLAS_THREADS``
(default 1): through threadpoolctl for the libraries already loaded, and through their
environment variables for those loaded later (the CLI imports numpy and scipy only once
a command runs, and threadpoolctl cannot limit a library not yet loaded). Library users
choose for themselves, e.g. ``with threadpoolctl.threadpool_limits(1): ...``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from threadpoolctl import threadpool_limits

from sarcomere.dynamics.errors import ParameterError

ENV = "SARCOMERE_BLAS_THREADS"
"""Environment variable: BLAS/LAPACK threads of a CLI command (a whole number >= 1)."""

#: Variables the thread pools read when their library loads (OpenBLAS, OpenMP, MKL, BLIS).
POOL_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def blas_threads() -> int:
    """The thread count asked for by :data:`ENV` (default 1)."""
    raw = os.environ.get(ENV, "1")
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise ParameterError(ENV, raw, "a whole number >= 1")
    return n


def limited_blas():
    """Context manager: the BLAS/LAPACK pools limited to :func:`blas_threads` threads,
    those of libraries loaded inside the block included; the environment is restored.
    A bad :data:`ENV` is refused here, before the block."""
    return _limited(blas_threads())


@contextmanager
def _limited(n: int) -> Iterator[None]:
    saved = {k: os.environ.get(k) for k in POOL_VARIABLES}
    os.environ.update(dict.fromkeys(POOL_VARIABLES, str(n)))
    try:
        with threadpool_limits(limits=n):
            yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
