"""Exceptions raised by sarcomere, each naming what was wrong and what is allowed."""

from __future__ import annotations


class SarcomereError(Exception):
    """Base class of every error sarcomere raises on purpose."""


class ParameterError(SarcomereError, ValueError):
    """A parameter has a bad value, unit or name.

    The message always names the parameter, the value given and the allowed range.
    """

    def __init__(self, name: str, value: object, allowed: str, reason: str = "") -> None:
        self.name, self.value, self.allowed = name, value, allowed
        why = f" ({reason})" if reason else ""
        super().__init__(f"parameter '{name}' = {value!r} is invalid{why}; allowed: {allowed}")


class ScenarioError(SarcomereError, ValueError):
    """A scenario file is malformed; names the file, the key and (if known) the line."""

    def __init__(self, file: str, key: str, message: str, line: int | None = None) -> None:
        self.file, self.key, self.line = file, key, line
        where = f"{file}:{line}" if line else file
        super().__init__(f"{where}: key '{key}': {message}")


class ModelError(SarcomereError):
    """A system cannot be assembled or flattened (bad connection, singular equations...)."""


class SolverError(SarcomereError, RuntimeError):
    """A numerical solver failed; says when, in which state and why.

    ``partial``: what a simulation computed up to the failure (``simulate``: a
    :class:`~sarcomere.dynamics.results.Result` of the output points before it, meta
    ``status = "incomplete"``), or None.
    """

    def __init__(self, message: str, time: float | None = None, state: dict | None = None) -> None:
        self.time, self.state = time, state or {}
        self.partial: object = None
        parts = [message]
        if time is not None:
            parts.append(f"at t = {time:.6g} s")
        if state:
            shown = ", ".join(f"{k}={v:.6g}" for k, v in list(state.items())[:12])
            parts.append(f"state: {shown}")
        super().__init__("; ".join(parts))
