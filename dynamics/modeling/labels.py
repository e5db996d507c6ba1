"""Signal labels for python-control: one reversible mapping of variable names.

A variable's name is its instance path (``"regulator.p_cmd"``). python-control 0.10
refuses ``.`` in signal names (it means ``system.signal`` in ``interconnect``), so a
python-control label joins the segments with ``__`` instead (``"regulator__p_cmd"``).
The mapping is exact because every segment is a :data:`NAME`: it starts with a letter
and has no ``__`` and no trailing ``_`` (checked when a component or variable is
declared). Labels that python-control itself makes (``interconnect`` prefixes states
with ``<system>_``) are not ours to map back.

Examples
--------
>>> to_label("myofibril.aps1.chamber.p_gauge")
'myofibril__aps1__chamber__p_gauge'
>>> from_label("myofibril__aps1__chamber__p_gauge")
'myofibril.aps1.chamber.p_gauge'
"""

from __future__ import annotations

import re

from ..errors import ParameterError

SEPARATOR = "__"
"""What replaces ``.`` in a python-control label."""

NAME = re.compile(r"^[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)*$")
"""One segment of a variable path: a letter, then letters and digits, joined by single
underscores (so ``__`` never occurs inside a segment)."""

NAME_RULE = "letters, digits and single inner underscores, starting with a letter"


def to_label(name: str) -> str:
    """The python-control label of a variable name: ``.`` -> ``__``.

    Raises
    ------
    ParameterError
        If a segment of ``name`` is not a :data:`NAME` (the label would not map back).
    """
    return SEPARATOR.join(_segments(name, ".", "name"))


def from_label(label: str) -> str:
    """The variable name of a python-control label: ``__`` -> ``.``.

    Raises
    ------
    ParameterError
        If ``label`` was not made by :func:`to_label`.
    """
    return ".".join(_segments(label, SEPARATOR, "label"))


def _segments(text: str, sep: str, what: str) -> list[str]:
    parts = text.split(sep)
    if not all(NAME.match(p) for p in parts):
        raise ParameterError(what, text, f"segments joined by '{sep}', each {NAME_RULE}")
    return parts
