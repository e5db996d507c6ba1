"""CasADi Functions called repeatedly on bound numpy buffers."""

from __future__ import annotations

import casadi as cs
import numpy as np


class BufferedCall:
    """Repeated calls of a CasADi Function on bound numpy arrays (``Function.buffer``):
    about 1 us of call overhead instead of some 30 us of conversions per argument.

    Arguments are arrays of each input's shape (matrices column-major, as CasADi stores
    them). Calling returns the first output's nonzeros, :meth:`outputs` every output's;
    copies, unless ``copy=False``: then the call's own arrays (:attr:`res`), overwritten by
    the next call. An input shared (:meth:`share`) with another call's output is read in
    place.
    """

    def __init__(self, F: cs.Function, copy: bool = True) -> None:
        self.function, self.copy = F, copy
        self.args = [np.zeros(F.nnz_in(i)) for i in range(F.n_in())]
        self.res = [np.zeros(F.nnz_out(i)) for i in range(F.n_out())]
        self.buf, self.trigger = F.buffer()
        for i, arr in enumerate(self.args):
            self.buf.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self.res):
            self.buf.set_res(i, memoryview(arr))

    def share(self, i: int, source: np.ndarray) -> None:
        """Read input ``i`` from ``source`` (another call's output array): passing that
        array as the argument then copies nothing."""
        self.args[i] = source
        self.buf.set_arg(i, memoryview(source))

    def outputs(self, *values: np.ndarray) -> list[np.ndarray]:
        """Every output's nonzeros (column-major) at ``values``."""
        for arr, value in zip(self.args, values, strict=True):
            if value is not arr:
                arr[:] = np.ravel(value, order="F")
        self.trigger()
        return [r.copy() for r in self.res] if self.copy else list(self.res)

    def __call__(self, *values: np.ndarray) -> np.ndarray:
        """The first output's nonzeros (column-major) at ``values``."""
        return self.outputs(*values)[0]
