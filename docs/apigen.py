"""The API reference, generated at build time from the packages' public names.

Every module under ``sarcomere`` whose source defines ``__all__`` gets a page listing its
names, plus the modules of :data:`CURATED` (the classes ``docs/architecture.md`` names in
modules without an ``__all__``). A new sub-package with an ``__all__`` (``dynamics/
identification/``, ...) appears without an edit here. Each object is documented once, at
its first public home in :func:`documented_modules`' order (packages before their modules);
other homes link to it. ``docs/tests/test_api_coverage.py`` checks the built inventory
against every ``__all__``, found independently.
"""

from __future__ import annotations

import pkgutil
import re
from importlib import import_module
from importlib.util import find_spec
from pathlib import Path

#: The top-level packages, in the order of the layers (docs/architecture.md).
PACKAGES = ("sarcomere.dynamics", "sarcomere.controllers", "sarcomere.fmu", "sarcomere.scenarios")

#: Modules without an ``__all__`` whose named classes and functions are public API:
#: the controllers' classes (built by the factories of ``sarcomere.controllers``) and the
#: closed loop.
CURATED = {
    "sarcomere.controllers.pid": ["PID", "PIDGains", "make_pid"],
    "sarcomere.controllers.lqi": ["LQI", "LQIWeights", "make_lqi"],
    "sarcomere.controllers.ekf": ["EKF", "make_ekf"],
    "sarcomere.controllers.lmpc": ["LinearMPC", "LMPCSettings", "make_lmpc"],
    "sarcomere.controllers.nmpc": ["NonlinearMPC", "NMPCSettings", "make_nmpc"],
    "sarcomere.controllers.loop": ["run_closed_loop"],
}

_ALL = re.compile(r"^__all__\s*[:=]", re.MULTILINE)


def _source_defines_all(name: str) -> bool:
    origin = getattr(find_spec(name), "origin", None)  # the module is not run
    return bool(origin and origin.endswith(".py") and _ALL.search(Path(origin).read_text()))


def documented_modules() -> dict[str, list[str]]:
    """Module -> its public names: each package, then its sub-modules with an ``__all__``
    and those of :data:`CURATED`, sorted by name."""
    found: dict[str, list[str]] = {}
    for package in PACKAGES:
        found[package] = list(import_module(package).__all__)
        paths = import_module(package).__path__
        for info in sorted(pkgutil.walk_packages(paths, package + "."), key=lambda i: i.name):
            if any(part.startswith("_") for part in info.name.split(".")):
                continue
            if _source_defines_all(info.name):
                found[info.name] = list(import_module(info.name).__all__)
    for module, names in CURATED.items():
        found.setdefault(module, [])
        found[module] += [n for n in names if n not in found[module]]
    top = {p: i for i, p in enumerate(PACKAGES)}

    def order(module: str) -> tuple[int, bool, str]:
        package = ".".join(module.split(".")[:2])
        return top[package], module != package, module

    return {m: found[m] for m in sorted(found, key=order)}


def _canonical(modules: dict[str, list[str]]) -> dict[int, str]:
    """id(object) -> the dotted name it is documented under (its first home)."""
    home: dict[int, str] = {}
    for module, names in modules.items():
        mod = import_module(module)
        for name in names:
            obj = getattr(mod, name)
            if _documentable(obj):
                home.setdefault(id(obj), f"{module}.{name}")
    return home


def _documentable(obj: object) -> bool:
    """Classes and functions are documented once; data (a dict, a tuple) per home."""
    return isinstance(obj, type) or callable(obj)


def _summary(module: str) -> str:
    doc = (import_module(module).__doc__ or "").strip()
    first = doc.split("\n\n")[0].replace("\n", " ")
    return first


def write_api(out: Path) -> list[str]:
    """Write ``out/index.rst`` and one page per module; returns the module names."""
    modules = documented_modules()
    home = _canonical(modules)
    out.mkdir(parents=True, exist_ok=True)
    index = [
        "API reference",
        "=============",
        "",
        "The public names of each package (its ``__all__``), in the order of the layers:",
        "``dynamics`` <- ``controllers`` <- ``fmu`` <- ``scenarios`` (a package imports",
        "only layers before it). Sub-modules with their own public names follow their",
        "package. Every quantity is SI unless its docstring says otherwise.",
        "",
        ".. toctree::",
        "   :hidden:",
        "",
        *(f"   {m}" for m in modules),
        "",
    ]
    for module, names in modules.items():
        own, aliases = _split(module, names, home)
        page = [module, "=" * len(module), "", f".. automodule:: {module}", "   :no-members:", ""]
        page += [f".. currentmodule:: {module}", ""]
        if own:
            page += [".. autosummary::", "   :toctree: generated", "", *(f"   {n}" for n in own)]
            page += [""]
        if aliases:
            page += ["Also importable from here (documented at their first home):", ""]
            page += [f"- :py:obj:`{module}.{n} <{target}>`" for n, target in aliases] + [""]
        (out / f"{module}.rst").write_text("\n".join(page))
        index += [f":doc:`{module}`", "-" * (len(module) + 7), "", _summary(module), ""]
        targets = [f"{module}.{n}" for n in own] + [t for _, t in aliases]
        index += [".. autosummary::", "", *(f"   ~{t}" for t in targets), ""]  # short names
    (out / "index.rst").write_text("\n".join(index))
    return list(modules)


def _split(module: str, names: list[str], home: dict[int, str]):
    mod = import_module(module)
    own, aliases = [], []
    for name in names:
        obj = getattr(mod, name)
        target = home.get(id(obj)) if _documentable(obj) else None
        if target is None or target == f"{module}.{name}":
            own.append(name)
        else:
            aliases.append((name, target))
    return own, aliases
