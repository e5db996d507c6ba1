"""Packages whose public names are imported on first use (PEP 562 module ``__getattr__``).

``import sarcomere.dynamics.errors`` or ``sarcomere.scenarios.cli`` then costs no CasADi,
SciPy or matplotlib import: the command line answers ``--version`` at once.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module


def lazy_exports(
    package: str, homes: Mapping[str, str], names: list[str]
) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    homes : mapping of str to str
        Public name -> module defining it, relative to ``package`` (``"modeling.model"``).
    names : list of str
        The package's ``__all__``.

    A name found in neither ``homes`` nor as a sub-module raises AttributeError.
    """

    def getattr_(name: str) -> object:
        if name in homes:
            value = getattr(import_module(f".{homes[name]}", package), name)
        else:
            try:
                value = import_module(f".{name}", package)
            except ModuleNotFoundError as exc:
                if exc.name != f"{package}.{name}":
                    raise
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        vars(import_module(package))[name] = value  # later lookups skip this function
        return value

    def dir_() -> list[str]:
        return sorted({*vars(import_module(package)), *names})

    return getattr_, dir_
