"""Named signals with units: what every solver, sweep and co-simulation returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import SarcomereError, SolverError


@dataclass
class Result:
    """A table of named signals over one index (time in s, or a sweep variable).

    Parameters
    ----------
    index_name : str
        Name of the index column, e.g. ``"time"`` or ``"pressure"``.
    index_unit : str
        SI unit of the index, e.g. ``"s"`` or ``"Pa"``.
    index : numpy.ndarray
        Index values, shape ``(N,)``, increasing.
    signals : dict of str to numpy.ndarray
        Signal name (the flattened variable path, e.g. ``"load.s"``) to values, shape ``(N,)``.
    units : dict of str to str
        Signal name to SI unit.
    meta : dict
        Free-form provenance: solver, fidelity, statistics.

    Examples
    --------
    >>> r = Result("time", "s", np.array([0.0, 1.0]), {"x": np.array([1.0, 2.0])}, {"x": "m"})
    >>> float(r["x"][-1])
    2.0
    """

    index_name: str
    index_unit: str
    index: np.ndarray
    signals: dict[str, np.ndarray]
    units: dict[str, str]
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.index = np.asarray(self.index, dtype=float)
        n = self.index.shape[0]
        for name, values in self.signals.items():
            arr = np.asarray(values, dtype=float)
            if arr.shape != (n,):
                raise SarcomereError(
                    f"signal '{name}' has shape {arr.shape}, expected ({n},) like the index"
                )
            self.signals[name] = arr
            self.units.setdefault(name, "1")

    def __getitem__(self, name: str) -> np.ndarray:
        if name == self.index_name:
            return self.index
        try:
            return self.signals[name]
        except KeyError:
            raise KeyError(
                f"no signal '{name}'; available: {', '.join(sorted(self.signals))}"
            ) from None

    def __contains__(self, name: str) -> bool:
        return name == self.index_name or name in self.signals

    @property
    def names(self) -> list[str]:
        """Signal names in insertion order (without the index)."""
        return list(self.signals)

    def final(self, name: str) -> float:
        """Last value of a signal."""
        return float(self[name][-1])

    def require_finite(self, source: str) -> Result:
        """This Result, or a :class:`SolverError` naming ``source`` (the method or level
        that produced it), the first non-finite signal and its index value."""
        for name, values in self.signals.items():
            bad = ~np.isfinite(values)
            if bad.any():
                at = float(self.index[np.argmax(bad)])
                raise SolverError(
                    f"{source}: signal '{name}' is {values[np.argmax(bad)]} at "
                    f"{self.index_name} = {at:.9g} {self.index_unit}"
                )
        return self

    def select(self, names: list[str]) -> Result:
        """A Result with only the named signals (same index and meta)."""
        return Result(
            self.index_name,
            self.index_unit,
            self.index,
            {n: self[n] for n in names},
            {n: self.units[n] for n in names},
            dict(self.meta),
        )
