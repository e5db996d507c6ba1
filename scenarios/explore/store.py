"""The Zarr store of a design study: one flat ``sample`` dimension, one chunk per task.

Layout (docs/studies.md, STUDY_INTERFACE): a variable per factor (written in full when the
store is made), per metric and per time-series signal (``series_<signal>``, dims
``("sample", "time")``), ``status`` (int8: -1 not computed, 0 ok, 1 failed, 2 worker lost
twice) and ``error`` (variable-length UTF-8 text, ``""`` when ok). The attributes hold the
study's canonical definition (JSON) and its fingerprint.

Guarantees:

- **Made atomically**: the store is built in a temporary sibling folder, factor values and
  definition included, and renamed into place; a store either exists whole or not at all.
- **One study per store**: opening an existing store with a different definition is
  refused, naming the keys that differ; an ``--out`` folder holding anything else than
  this study's store and the files written beside it is refused.
- **One writer**: a run holds an exclusive lock on ``--out`` (``fcntl.flock`` on
  ``.study.lock`` in it) from before the store is made until its outputs are written; a
  second run on the same folder is refused naming the process that holds it.
- **Loss-free writes**: a finished task's samples are one chunk of every variable; the
  chunk files are written atomically (Zarr's local store writes a temporary file and
  renames it) and ``status`` last, so a run killed at any instant leaves every chunk
  either complete or still at status -1, which a re-run recomputes.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import warnings
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError, SarcomereError

#: Folder name of the store inside the study's ``--out`` folder.
STORE_NAME = "study.zarr"

#: Attribute marking a Zarr group as a sarcomere study store (its layout version).
MARKER = "sarcomere_study_store"
LAYOUT_VERSION = 1

#: Status codes of a sample.
NOT_COMPUTED, OK, FAILED, WORKER_LOST = -1, 0, 1, 2

#: Bytes per sample of ``status`` and a typical empty ``error`` in the size estimate.
_STATUS_ERROR_BYTES = 1 + 8

_TMP_PREFIX = f".{STORE_NAME}."

#: The lock file of a study's ``--out`` folder (holds the writer's process id).
LOCK_NAME = ".study.lock"


@functools.cache
def _writers() -> ThreadPoolExecutor:
    """The threads writing chunks (one pool per process)."""
    return ThreadPoolExecutor(8, thread_name_prefix="study-store")


class StoreError(SarcomereError):
    """A study store cannot be used: another study's, or not a study store at all."""


@dataclass(frozen=True)
class Column:
    """One per-sample variable of the store: ``name``, SI ``unit`` and ``long_name``."""

    name: str
    unit: str
    long_name: str


def series_name(signal: str) -> str:
    """The store variable holding the time series of ``signal``."""
    return f"series_{signal}"


def estimated_bytes(n_samples: int, n_factors: int, n_metrics: int, series_points: int) -> int:
    """Uncompressed size of a full store [bytes]: float64 factors, metrics and series
    values, int8 status and a short error string per sample."""
    per_sample = 8 * (n_factors + n_metrics + series_points) + _STATUS_ERROR_BYTES
    return n_samples * per_sample


def _short(value: object, width: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def _by_name(value: object) -> object:
    """A list of dicts that all have a ``name`` as a dict by name (compared by name)."""
    if (
        isinstance(value, list)
        and value
        and all(isinstance(v, dict) and "name" in v for v in value)
    ):
        return {str(v["name"]): v for v in value}
    return value


def definition_diff(stored: object, given: object, path: str = "", limit: int = 6) -> list[str]:
    """Human-readable differences between two JSON-like definitions, as
    ``"key.path: stored -> given"`` lines (at most ``limit``, long values shortened)."""
    stored, given = _by_name(stored), _by_name(given)
    out: list[str] = []
    if isinstance(stored, dict) and isinstance(given, dict):
        for key in sorted(set(stored) | set(given), key=str):
            where = f"{path}.{key}" if path else str(key)
            if key not in given:
                out.append(f"{where}: {_short(stored[key])} -> (absent)")
            elif key not in stored:
                out.append(f"{where}: (absent) -> {_short(given[key])}")
            else:
                out += definition_diff(stored[key], given[key], where, limit)
            if len(out) >= limit:
                break
    elif isinstance(stored, list) and isinstance(given, list) and len(stored) == len(given):
        for i, (a, b) in enumerate(zip(stored, given, strict=True)):
            out += definition_diff(a, b, f"{path}.{i}" if path else str(i), limit)
    elif stored != given:
        out.append(f"{path or '(definition)'}: {_short(stored)} -> {_short(given)}")
    return out[:limit]


def check_out_folder(out: Path, name: str = "--out") -> Path:
    """The store path inside ``out``; refuses a folder that is neither new, empty, nor
    holding a study store (before any work: the definition is compared on opening)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ParameterError(name, str(out), "a folder (new, empty or holding a study.zarr)")
    store = out / STORE_NAME
    if out.is_dir() and not store.exists():
        others = sorted(
            p.name
            for p in out.iterdir()
            if not p.name.startswith(_TMP_PREFIX) and p.name != LOCK_NAME
        )
        if others:
            shown = ", ".join(others[:5]) + (", ..." if len(others) > 5 else "")
            raise ParameterError(
                name,
                str(out),
                f"a new or empty folder, or one holding a study's {STORE_NAME}",
                f"it holds {shown} and no {STORE_NAME}",
            )
    return store


@contextmanager
def locked(out: Path) -> Iterator[None]:
    """Hold the exclusive lock of the study folder ``out`` (made if missing) while the
    block runs; a StoreError naming the holder's process if another run holds it. The
    lock goes with the process (a killed run leaves none)."""
    import fcntl

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise StoreError(
                f"--out: {out} is in use by process {holder} (another study run writes "
                "there); wait for it to finish or use another folder"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)


class StudyStore:
    """An open study store: its path, sample count and chunk (task) size."""

    def __init__(self, path: Path, group) -> None:
        self.path = Path(path)
        self._group = group
        self._arrays = dict(group.arrays())
        self.n_samples = int(group["status"].shape[0])
        self.chunk = int(group["status"].chunks[0])

    # -- making and opening ---------------------------------------------------------------
    @classmethod
    def open_or_create(
        cls,
        path: Path,
        *,
        definition: dict,
        fingerprint: str,
        factors: list[tuple[Column, np.ndarray]],
        metrics: list[Column],
        series: list[Column],
        series_time: np.ndarray | None,
        chunk: int,
        attrs: dict,
    ) -> StudyStore:
        """Open the study's store at ``path``, making it (atomically) if absent.

        Parameters
        ----------
        definition, fingerprint
            The study's canonical definition and its fingerprint (stored as attributes;
            an existing store with another fingerprint is refused with the differences).
        factors : list of (Column, float64 array of the sample count)
            Factor variables and their values per sample (SI).
        metrics, series : list of Column
            Metric variables and time-series signals.
        series_time : float64 array or None
            The series' time grid [s] (None when there is no series).
        chunk : int
            Samples per chunk = per task.
        attrs : dict
            Further JSON-serialisable attributes (base, kind, method, seed, ...).
        """
        path = Path(path)
        if not path.exists():
            cls._create(
                path, definition, fingerprint, factors, metrics, series, series_time, chunk, attrs
            )
        return cls.open(path, definition, fingerprint)

    @classmethod
    def open(
        cls, path: Path, definition: dict | None = None, fingerprint: str | None = None
    ) -> StudyStore:
        """Open an existing store; refuses a folder that is not a study store, and one of
        another study than ``definition`` (with ``fingerprint``) when given."""
        import zarr

        path = Path(path)
        try:
            group = zarr.open_group(str(path), mode="r+")
            ok = group.attrs.get(MARKER) == LAYOUT_VERSION and "status" in group
        except Exception as exc:  # zarr raises several kinds for a non-store folder
            raise StoreError(
                f"--out: {path} is not a sarcomere study store ({type(exc).__name__}: {exc}); "
                "allowed: a new or empty folder, or one holding a study's store"
            ) from None
        if not ok:
            raise StoreError(
                f"--out: {path} is a Zarr group but not a sarcomere study store (no "
                f"'{MARKER}' = {LAYOUT_VERSION} attribute); use a new or empty folder"
            )
        store = cls(path, group)
        if fingerprint is not None:
            store._check_definition(definition, fingerprint)
        return store

    @staticmethod
    def _create(path, definition, fingerprint, factors, metrics, series, series_time, chunk, attrs):
        import zarr

        n = len(factors[0][1]) if factors else 0
        if n < 1 or chunk < 1:
            raise ParameterError("samples per task", chunk, "a study with >= 1 sample and >= 1")
        path.parent.mkdir(parents=True, exist_ok=True)
        for stale in path.parent.glob(_TMP_PREFIX + "*"):  # a run killed while making one
            shutil.rmtree(stale, ignore_errors=True)
        tmp = path.parent / f"{_TMP_PREFIX}{os.getpid()}.tmp"
        group = zarr.open_group(str(tmp), mode="w", zarr_format=3)

        def column(col: Column, dtype, fill, dims=("sample",), shape=(n,), chunks=(chunk,)):
            return group.create_array(
                col.name,
                shape=shape,
                chunks=chunks,
                dtype=dtype,
                fill_value=fill,
                dimension_names=dims,
                attributes={"unit": col.unit, "long_name": col.long_name},
            )

        for col, values in factors:
            column(col, "float64", np.nan)[:] = np.asarray(values, dtype=np.float64)
        for col in metrics:
            column(col, "float64", np.nan)
        if series:
            t = np.asarray(series_time, dtype=np.float64)
            column(Column("time", "s", "time"), "float64", np.nan, ("time",), t.shape, t.shape)[
                :
            ] = t
            for col in series:
                column(col, "float64", np.nan, ("sample", "time"), (n, t.size), (chunk, t.size))
        column(Column("status", "1", "sample status"), "int8", NOT_COMPUTED).attrs.update(
            flag_values=[NOT_COMPUTED, OK, FAILED, WORKER_LOST],
            flag_meanings="not_computed ok failed worker_lost_twice",
        )
        column(Column("error", "1", "error message"), str, "")
        group.attrs.update(
            {
                **attrs,
                MARKER: LAYOUT_VERSION,
                "study": json.dumps(definition, sort_keys=True),
                "fingerprint": fingerprint,
                "created": datetime.now(UTC).isoformat(timespec="seconds"),
            }
        )
        with warnings.catch_warnings():  # "not part of the Zarr 3 specification (yet)"
            warnings.simplefilter("ignore")
            zarr.consolidate_metadata(str(tmp))  # readers open it without listing it
        try:
            os.rename(tmp, path)
        except OSError:  # another run made it first: use theirs (compared on opening)
            shutil.rmtree(tmp, ignore_errors=True)
            if not path.exists():
                raise

    def _check_definition(self, definition: dict, fingerprint: str) -> None:
        stored_fp = self._group.attrs.get("fingerprint")
        if stored_fp == fingerprint:
            return
        stored = json.loads(self._group.attrs.get("study", "{}"))
        diff = definition_diff(stored, json.loads(json.dumps(definition)))
        raise StoreError(
            f"--out: {self.path} holds another study (fingerprint {str(stored_fp)[:12]} != "
            f"{fingerprint[:12]}); differences (stored -> this study): "
            + "; ".join(diff or ["(same keys; definition canonicalisation changed)"])
            + ". Use another --out folder or remove the store."
        )

    # -- state ----------------------------------------------------------------------------
    @property
    def attrs(self) -> dict:
        """The store's attributes."""
        return dict(self._group.attrs)

    def status(self) -> np.ndarray:
        """Status of every sample (int8; -1 = not computed)."""
        return np.asarray(self._group["status"][:])

    def missing_chunks(self) -> list[tuple[int, int]]:
        """``(start, stop)`` sample ranges of the chunks with samples not computed."""
        status = self.status()
        out = []
        for start in range(0, self.n_samples, self.chunk):
            stop = min(start + self.chunk, self.n_samples)
            if (status[start:stop] == NOT_COMPUTED).any():
                out.append((start, stop))
        return out

    # -- writing --------------------------------------------------------------------------
    def write(self, start: int, result) -> None:
        """Write a finished task's result for the chunk starting at ``start`` (see
        :meth:`write_many`)."""
        self.write_many([(start, result)])

    def write_many(self, chunks: Sequence[tuple[int, object]]) -> None:
        """Write finished tasks' results, each ``(start, result)`` for the chunk starting
        at ``start``: all values of all chunks, then their statuses (see the module's
        guarantees).

        A result has ``indices`` (exactly the chunk's samples, in order), ``metrics``
        {name: float64}, ``series`` {signal: float64[len, T]}, ``status`` and ``error``.
        """
        values, statuses = [], []
        for start, result in chunks:
            rows = self._rows(start, result)
            for name, v in result.metrics.items():
                values.append((name, rows, np.asarray(v, np.float64)))
            for signal, v in (result.series or {}).items():
                values.append((series_name(signal), rows, np.asarray(v, np.float64)))
            errors = np.array([str(e) for e in result.error], dtype=object)
            values.append(("error", rows, errors))
            statuses.append(("status", rows, np.asarray(result.status, dtype=np.int8)))
        self._set(values)  # each chunk file is written atomically; then:
        self._set(statuses)

    def _rows(self, start: int, result) -> slice:
        """The chunk's rows, checked against the result's sample indices."""
        stop = min(start + self.chunk, self.n_samples)
        indices = np.asarray(result.indices)
        if start % self.chunk or not np.array_equal(indices, np.arange(start, stop)):
            raise StoreError(
                f"internal: a result for samples {indices[:3]}... is not the chunk "
                f"[{start}, {stop}) of {self.path}"
            )
        return slice(start, stop)

    def _set(self, writes: list[tuple[str, slice, np.ndarray]]) -> None:
        """Write each ``(variable, rows, values)`` through Zarr's public array API from a
        few threads at once (one chunk file each, written atomically by Zarr's local
        store): as cheap in CPU as one batch on Zarr's event loop, a fifth less than one
        write after the other (BENCHMARKS.md, "Design studies")."""

        def put(write: tuple[str, slice, np.ndarray]) -> None:
            name, rows, values = write
            self._arrays[name][rows] = values

        list(_writers().map(put, writes))  # re-raises the first failure

    # -- reading --------------------------------------------------------------------------
    def read(self):
        """The whole store as an in-memory xarray Dataset (dims ``sample`` [, ``time``])."""
        import xarray as xr

        ds = xr.open_zarr(str(self.path)).load()
        error = ds["error"]  # numpy StringDType -> Python str objects (the usual text dtype)
        ds["error"] = error.copy(data=np.array([str(e) for e in error.values], dtype=object))
        return ds
