"""The packaged scenarios, found without loading them, and the installed version
(``sarcomere list`` and ``--version`` stay light).

>>> "step-50g" in packaged_scenarios()
True
>>> heading(packaged_scenarios()["paper-static"])["kind"]
'static'
"""

from __future__ import annotations

import tomllib
from importlib import metadata, resources
from importlib.resources.abc import Traversable


def packaged_scenarios() -> dict[str, Traversable]:
    """Scenarios shipped with the package: name -> resource, sorted by name."""
    root = resources.files("sarcomere.scenarios")
    found = {p.name.removesuffix(".toml"): p for p in root.iterdir() if p.name.endswith(".toml")}
    return dict(sorted(found.items()))


def heading(resource: Traversable) -> dict:
    """The ``[scenario]`` table of a scenario file as written (not checked: see
    :func:`~sarcomere.scenarios.loader.load_scenario`)."""
    return tomllib.loads(resource.read_text(encoding="utf-8")).get("scenario", {})


def version() -> str:
    """The installed sarcomere version, or ``"unknown"``."""
    try:
        return metadata.version("sarcomere")
    except metadata.PackageNotFoundError:
        return "unknown"
