"""Shared libraries compiled from C sources, cached on disk by content hash.

The cache folder is ``$SARCOMERE_CACHE_DIR``, else ``$XDG_CACHE_HOME/sarcomere``, else
``~/.cache/sarcomere``; libraries live in its ``lib/`` folder as ``<stem>-<key>.so``.
The key is the SHA-256 of what the caller says the library depends on (its sources, or
what generates them deterministically, and its flags), the compiler (resolved path and
``--version``), the link flags, the platform and the Python ABI: any change builds a new
file, an unchanged set reuses the old one without invoking the compiler. Several
processes may build the same library at once: each compiles in its own temporary
folder, copies the result to a temporary file in ``lib/`` and renames it into place
(``os.replace``, atomic), so a reader sees no file or a whole one. Delete
the folder to clear the cache (``docs/numerics.md``).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as cs
import numpy as np

from ..errors import SolverError


@dataclass(frozen=True)
class Unit:
    """One translation unit: a C source and its compiler flags."""

    source: Path
    flags: tuple[str, ...]


def cache_dir() -> Path:
    """The cache folder (``SARCOMERE_CACHE_DIR``, XDG, or ``~/.cache/sarcomere``)."""
    env = os.environ.get("SARCOMERE_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "sarcomere"


def compiler() -> str:
    """The C compiler's path (``$CC``, default gcc); a SolverError if there is none."""
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        raise SolverError("no C compiler found: install gcc or set CC")
    return cc


@functools.cache
def _compiler_id(cc: str) -> str:
    done = subprocess.run([cc, "--version"], capture_output=True, text=True, check=False)
    return f"{os.path.realpath(cc)}\n{done.stdout}"


def key(inputs: Sequence[bytes | str], link_flags: Sequence[str] = ()) -> str:
    """The content hash (hex, 24 characters) of a library built from ``inputs`` (whatever
    determines its sources and flags) with the compiler, platform and Python ABI here."""
    h = hashlib.sha256()
    for part in (
        _compiler_id(compiler()),
        platform.platform(),
        platform.machine(),
        sysconfig.get_config_var("SOABI") or sys.version,
        " ".join(link_flags),
        *inputs,
    ):
        h.update((part.encode() if isinstance(part, str) else part) + b"\0")
    return h.hexdigest()[:24]


def library_path(
    stem: str, inputs: Sequence[bytes | str], link_flags: Sequence[str] = ("-lm",)
) -> Path:
    """Where :func:`shared_library` keeps the library keyed by ``inputs`` (it may be
    absent: ``.is_file()``); no compile."""
    return cache_dir() / "lib" / f"{stem}-{key(inputs, link_flags)}.so"


def shared_library(
    stem: str,
    inputs: Sequence[bytes | str],
    units: Callable[[Path], Sequence[Unit]],
    link_flags: Sequence[str] = ("-lm",),
) -> tuple[Path, bool]:
    """The cached shared library keyed by ``inputs``, built first if absent.

    Parameters
    ----------
    stem : str
        File name prefix.
    inputs : sequence of bytes or str
        Everything the library depends on besides the compiler and platform: the
        sources (or what generates them, deterministically) and the flags.
    units : callable
        ``units(folder)``: writes the sources into ``folder`` and returns the units;
        called only if the library is not in the cache. The units compile in parallel
        (one compiler process each), then link.

    Returns
    -------
    (Path, bool)
        The library's path in the cache, and whether this call compiled it.
    """
    path = library_path(stem, inputs, link_flags)
    if path.is_file():
        return path, False
    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SolverError(
            f"cannot create the compile cache folder {folder} ({e.strerror}): "
            "set SARCOMERE_CACHE_DIR to a writable folder"
        ) from None
    with tempfile.TemporaryDirectory(prefix="sarcomere-build-") as tmp:
        built = _compile(units(Path(tmp)), link_flags, Path(tmp))
        fd, part = tempfile.mkstemp(prefix=f".{stem}-", suffix=".part", dir=folder)
        try:
            with os.fdopen(fd, "wb") as out, built.open("rb") as src:
                shutil.copyfileobj(src, out)
                out.flush()
                os.fsync(out.fileno())
            os.chmod(part, 0o755)
            os.replace(part, path)  # atomic: readers see no file or the whole one
        except BaseException:
            Path(part).unlink(missing_ok=True)
            raise
    return path, True


def _compile(units: Sequence[Unit], link_flags: Sequence[str], tmp: Path) -> Path:
    """Compile each unit to an object (in parallel), link them; the library's path."""
    cc = compiler()
    jobs = []
    for k, u in enumerate(units):
        obj = tmp / f"u{k}.o"
        cmd = [cc, "-c", "-fPIC", *u.flags, str(u.source), "-o", str(obj)]
        jobs.append((obj, subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)))
    errors = [p.communicate()[1] for _, p in jobs]
    for (_, p), err in zip(jobs, errors, strict=True):
        if p.returncode != 0:
            raise SolverError(f"the C compiler failed: {err[-2000:]}")
    so = tmp / "lib.so"
    cmd = [cc, "-shared", *(str(o) for o, _ in jobs), "-o", str(so), *link_flags]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SolverError(f"the linker failed: {done.stderr[-2000:]}")
    return so


CASADI_CFLAGS = ("-O2",)
"""Compiler flags of C generated from CasADi Functions (-O3 gave no measurable gain)."""


def casadi_library(
    functions: Sequence[cs.Function],
    stem: str,
    flags: Sequence[str] = (),
    link_flags: Sequence[str] = ("-lm",),
) -> dict[str, cs.Function]:
    """CasADi ``functions`` generated to C (``casadi.CodeGenerator``), compiled into one
    shared library in the disk cache (keyed by their serialised form, CasADi's version and
    the flags: the same Functions load the cached file without compiling) and loaded back
    with ``casadi.external``, by name, with the same inputs and outputs.

    ``flags``: extra compiler flags (include folders); ``link_flags``: what to link.
    Raises SolverError when a Function cannot be generated to C (e.g. a LAPACK linear
    solver or a rootfinder plugin without code generation) or the compiler fails.
    """
    path = _generated(functions, stem, (*CASADI_CFLAGS, *flags), link_flags)
    return {f.name(): cs.external(f.name(), str(path)) for f in functions}


def numpy_library(functions: Sequence[cs.Function], stem: str) -> dict[str, NumpyFunction]:
    """Like :func:`casadi_library`, but each Function is called through ctypes on numpy
    arrays (:class:`NumpyFunction`): no conversion to and from CasADi matrices, which
    costs more than the C itself for outputs of 1e5 entries."""
    handle = ctypes.CDLL(str(_generated(functions, stem, CASADI_CFLAGS, ("-lm",))))
    return {f.name(): NumpyFunction(f, handle) for f in functions}


def _generated(
    functions: Sequence[cs.Function], stem: str, cflags: Sequence[str], link_flags: Sequence[str]
) -> Path:
    """The cached library of ``functions`` generated to C (built first if absent)."""
    inputs = [f.serialize() for f in functions] + [cs.__version__, " ".join(cflags)]

    def units(folder: Path) -> list[Unit]:
        cg = cs.CodeGenerator(f"{stem}.c", {"with_header": False})
        for f in functions:
            cg.add(f)
        source = cg.dump()
        if "#error" in source:
            line = next(s for s in source.splitlines() if "#error" in s).strip()
            raise SolverError(f"{stem}: cannot generate C ({line})")
        path = folder / f"{stem}.c"
        path.write_text(source)
        return [Unit(path, tuple(cflags))]

    return shared_library(stem, inputs, units, tuple(link_flags))[0]


class NumpyFunction:
    """A generated CasADi Function called on numpy arrays: inputs dense (any shape with
    the right number of entries, read column-major as CasADi stores them), outputs dense
    arrays of the Function's shapes. Not thread-safe (one work area per object)."""

    def __init__(self, f: cs.Function, handle: ctypes.CDLL) -> None:
        name = f.name()
        self.name = name
        self._call = getattr(handle, name)
        self._call.restype = ctypes.c_int
        sizes = [ctypes.c_longlong() for _ in range(4)]
        getattr(handle, f"{name}_work")(*(ctypes.byref(z) for z in sizes))
        n_arg, n_res, n_iw, n_w = (int(z.value) for z in sizes)
        getattr(handle, f"{name}_incref")()
        self._mem = int(getattr(handle, f"{name}_checkout")())
        self._iw = np.zeros(max(n_iw, 1), dtype=np.int64)
        self._w = np.zeros(max(n_w, 1))
        self._iw_ptr = self._iw.ctypes.data_as(ctypes.c_void_p)
        self._w_ptr = self._w.ctypes.data_as(ctypes.c_void_p)
        self._arg = (ctypes.c_void_p * max(n_arg, 1))()
        self._res = (ctypes.c_void_p * max(n_res, 1))()
        self._shapes_in = [(f.size1_in(i), f.size2_in(i)) for i in range(f.n_in())]
        for i in range(f.n_in()):
            if not f.sparsity_in(i).is_dense():
                raise SolverError(f"{name}: input {i} is sparse (dense inputs only)")
        self._out = []
        for i in range(f.n_out()):
            sp = f.sparsity_out(i)
            rows, cols = sp.get_triplet()
            self._out.append(
                (sp.shape, sp.nnz(), np.array(rows, int), np.array(cols, int), sp.is_dense())
            )
        # one buffer per input and output, their addresses set once (numpy's ``ctypes.data``
        # costs more per call than the copies)
        self._inputs = [np.empty(r * c) for r, c in self._shapes_in]
        self._outputs = [np.empty(nnz) for _, nnz, _, _, _ in self._out]
        for i, buf in enumerate(self._inputs):
            self._arg[i] = buf.ctypes.data
        for i, buf in enumerate(self._outputs):
            self._res[i] = buf.ctypes.data

    def __call__(self, *args) -> list[np.ndarray]:
        if len(args) != len(self._inputs):
            raise TypeError(f"{self.name}: {len(args)} inputs given, {len(self._inputs)} taken")
        for i, (a, buf) in enumerate(zip(args, self._inputs, strict=True)):
            a = np.asarray(a, dtype=float)
            if a.size != buf.size:
                shape = self._shapes_in[i]
                raise ValueError(f"{self.name}: input {i} has {a.size} entries, not {shape}")
            buf[:] = a.ravel(order="F")  # column-major, as CasADi reads it
        rc = self._call(self._arg, self._res, self._iw_ptr, self._w_ptr, self._mem)
        if rc:
            raise SolverError(f"{self.name}: the generated C returned {rc}")
        out = []
        for r, (shape, _, rows, cols, dense) in zip(self._outputs, self._out, strict=True):
            if dense:
                out.append(r.copy().reshape(shape[::-1]).T)
            else:
                full = np.zeros(shape)
                full[rows, cols] = r
                out.append(full)
        return out
