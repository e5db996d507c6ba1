"""BLAS/LAPACK thread pools for the command line.

The models here are small (tens to a few hundred states): a multi-threaded BLAS only adds
synchronisation, and on a machine whose cores are busy it stalls. Measured on the 2-core
CI-class machine with the other core loaded: scipy ``expm`` of a 20 x 20 matrix took
1.6-8.8 ms with OpenBLAS's default threads and 0.036 ms with one (BENCHMARKS.md s6).
The CLI therefore runs every command with the pools limited to ``SARCOMERE_BLAS_THREADS``
(default 1) through threadpoolctl; library users choose for themselves, e.g.
``with threadpoolctl.threadpool_limits(1): ...``.
"""

from __future__ import annotations

import os

from threadpoolctl import threadpool_limits

from sarcomere.dynamics.errors import ParameterError

ENV = "SARCOMERE_BLAS_THREADS"
"""Environment variable: BLAS/LAPACK threads of a CLI command (a whole number >= 1)."""


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
    """Context manager: the BLAS/LAPACK pools limited to :func:`blas_threads` threads."""
    return threadpool_limits(limits=blas_threads())
