"""Every public name is in the API reference (as python-control's ``test_sphinxdocs.py``):
the modules are found here by walking the packages pyproject.toml installs, not from the
list the build used (``docs/apigen.py``), and checked against the built site's inventory."""

from __future__ import annotations

import pkgutil
import sys
import tomllib
from importlib import import_module
from pathlib import Path

import pytest
from sphinx.util.inventory import InventoryFile

DOCS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(DOCS))

import conf  # noqa: E402  (docs/conf.py: its cross-reference rule is tested below)


def public_names() -> dict[str, list[str]]:
    """Module -> its ``__all__``, for every module of every package pyproject.toml lists."""
    project = tomllib.loads((DOCS.parent / "pyproject.toml").read_text(encoding="utf-8"))
    modules = set()
    for package in project["tool"]["setuptools"]["packages"]:
        modules.add(package)
        for info in pkgutil.iter_modules(import_module(package).__path__, package + "."):
            modules.add(info.name)
    found = {}
    for name in sorted(modules):
        if any(part.startswith("_") for part in name.split(".")):
            continue
        module = import_module(name)
        if "__all__" in vars(module):
            found[name] = list(module.__all__)
    return found


def _inventory(html: Path) -> dict[str, str]:
    with open(html / "objects.inv", "rb") as f:
        inv = InventoryFile.load(f, "", lambda base, uri: uri)
    names = {}
    for kind, entries in inv.data.items() if hasattr(inv, "data") else inv.items():
        if kind.startswith("py:"):
            for name, item in entries.items():
                names[name] = getattr(item, "uri", None) or item[2]
    return names


def test_the_walk_finds_the_layers_and_their_modules():
    found = public_names()
    assert {"sarcomere.dynamics", "sarcomere.controllers", "sarcomere.fmu"} <= set(found)
    assert "Study" in found["sarcomere.scenarios"]
    assert "paper_static" in found["sarcomere.dynamics.paper"]  # a module, not a package
    assert sum(map(len, found.values())) > 150


def test_every_public_name_is_documented(html):
    inventory = _inventory(html)
    documented = set()
    for name in inventory:
        module, _, attr = name.rpartition(".")
        try:
            documented.add(id(getattr(import_module(module), attr)))
        except (ImportError, AttributeError, ValueError):
            continue
    missing = []
    for module, names in public_names().items():
        for name in names:
            obj = getattr(import_module(module), name)
            here = f"{module}.{name}" in inventory
            elsewhere = (isinstance(obj, type) or callable(obj)) and id(obj) in documented
            if not (here or elsewhere):
                missing.append(f"{module}.{name}")
    assert not missing, f"public names missing from the API reference: {missing}"


@pytest.mark.parametrize(
    "name",
    [
        "sarcomere.dynamics.simulate",
        "sarcomere.fmu.export_fmu",
        "sarcomere.controllers.nmpc.NonlinearMPC",
        "sarcomere.scenarios.Study",
    ],
)
def test_the_entry_points_have_their_own_page(html, name):
    uri = _inventory(html)[name].split("#")[0]
    assert (html / uri).is_file(), uri
    assert name.rsplit(".", 1)[1] in (html / uri).read_text(encoding="utf-8")


def test_a_reference_to_a_renamed_name_stays_an_error():
    """conf.missing_reference lets a reference to an existing object outside the reference
    render as code; one to nothing must still fail the -n build."""
    assert conf._resolve("sarcomere.dynamics.simulate", None, None)
    assert conf._resolve("ca.SX", "sarcomere.dynamics", None)  # a TYPE_CHECKING alias
    assert conf._resolve("signal_names", "sarcomere.dynamics", "Model")  # set in __init__
    assert conf._resolve(".rti.Prediction.backoffs", "sarcomere.controllers.nmpc", None)
    assert not conf._resolve("simulate_renamed", "sarcomere.dynamics", None)
    assert not conf._resolve("Model.no_such_method", "sarcomere.dynamics", None)
    assert not conf._resolve("numpy.no_such_thing", "sarcomere.dynamics", None)
