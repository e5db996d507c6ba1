"""The NMPC real-time iteration's CasADi Functions generated to C, compiled and cached.

:func:`compiled_functions` turns pure CasADi Functions (the RTI's ``nmpc_prepare``,
``nmpc_feedback`` and ``nmpc_update`` with the kept sparse LU of
:mod:`~sarcomere.dynamics.simulation.sparse_lu`, whose
per-interval Functions are generated once and called in loops; with a LAPACK solver, the
linearisation ``nmpc_head`` and condensing ``nmpc_tail`` around it; or a whole law built
with a code-generable linear solver,
``"sparse_lu"`` or ``"qr"``) into one shared library:
``casadi.CodeGenerator`` writes the C and gcc compiles it
(:func:`sarcomere.dynamics.simulation.compiled.casadi_library`); the library lives in the
disk cache of :mod:`sarcomere.dynamics.simulation.compiled` (keyed
by the Functions' serialised form, CasADi's version and the flags: a rebuilt controller of
the same problem loads the cached file without compiling). The QP solver DAQP's generated
C calls the DAQP library; it is linked statically from the copy the casadi wheel ships
(``libdaqpstat.a``, headers in ``casadi/include``), so the library needs nothing beyond
libc and libm. Each Function is loaded back with ``casadi.external`` and called like the
original.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import casadi as cs

from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.simulation import compiled

_CASADI = Path(cs.__file__).parent


def daqp_build() -> tuple[list[str], list[str]]:
    """Compiling C that CasADi generated with DAQP inside: the compiler flag for its
    headers and the static archive to link (the linker takes only what the C calls), both
    from the installed casadi wheel; the one place that finds them (the LMPC law, the
    compiled RTI, the controller FMU)."""
    lib = _CASADI / "libdaqpstat.a"
    if not (lib.is_file() and (_CASADI / "include" / "daqp").is_dir()):
        raise SolverError(f"the DAQP headers or static library are not in {_CASADI}")
    return [f"-I{_CASADI / 'include'}"], [str(lib)]


def compiled_functions(functions: Sequence[cs.Function], stem: str) -> dict[str, cs.Function]:
    """The ``functions`` compiled into one cached shared library, by name, with DAQP's
    headers and static library (:func:`daqp_build`); see
    :func:`sarcomere.dynamics.simulation.compiled.casadi_library`.

    Returns
    -------
    dict of str to casadi.Function
        ``casadi.external`` Functions of the same names, inputs and outputs.

    Raises
    ------
    SolverError
        When a Function cannot be generated to C (e.g. a LAPACK linear solver), or the
        compiler fails.
    """
    include, link = daqp_build()
    return compiled.casadi_library(functions, stem, include, (*link, "-lm"))
