"""Sphinx configuration: the Markdown pages (myst), the API reference generated from the
packages' ``__all__`` (``apigen.py``), the example gallery (``examples/plot_*.py``).

Build (warnings are errors, every cross reference checked, offline)::

    sphinx-build -W --keep-going -n docs docs/_build/html
    sphinx-build -W --keep-going -n -D plot_gallery=0 docs docs/_build/fast  # no examples run
"""

from __future__ import annotations

import builtins
import inspect
import os
import re
import sys
from importlib import import_module
from pathlib import Path

from sphinx.pycode import ModuleAnalyzer

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import apigen  # noqa: E402  (beside this file)
import landing  # noqa: E402

project = "sarcomere"
author = "the sarcomere authors"
copyright = "the sarcomere authors, MIT licence"  # noqa: A001
release = version = import_module("importlib.metadata").version("sarcomere")

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = [
    "_build",
    "_generated",
    "tests",
    "gallery/*.ipynb",
    "gallery/*.py",
    "**.zip",
    "**.json",
]
templates_path = ["_templates"]
nitpicky = True
suppress_warnings: list[str] = []

# --- Markdown (the docs/*.md pages as they are on the repository page) -------------------
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# --- the API reference ---------------------------------------------------------------------
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_class_signature = "mixed"
numpydoc_show_class_members = False  # autodoc lists the members
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False  # type texts ("mapping of str to float") stay text
numpydoc_validation_checks: set[str] = set()
add_module_names = False

# --- the gallery ---------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": str(HERE.parent / "examples"),
    "gallery_dirs": "gallery",
    "filename_pattern": r"/plot_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "show_memory": False,
    "min_reported_time": 1,
    "abort_on_example_error": True,
    "only_warn_on_example_error": False,
    "capture_repr": (),
    "reference_url": {},
    "first_notebook_cell": None,
}
os.environ.setdefault("MPLBACKEND", "agg")

# --- HTML ----------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"sarcomere {release}"
html_static_path = ["_static"]
html_favicon = "_static/favicon.svg"  # else every page asks for /favicon.ico (a 404)
html_context = {"default_mode": "auto"}  # else the theme's script logs "invalid theme mode"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 3,  # the pages' titles are long
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_show_sourcelink = False


#: The conventional import aliases of the annotations (``ca.SX``, ``np.ndarray``).
ALIASES = {"ca": "casadi", "cs": "casadi", "np": "numpy", "ct": "control", "xr": "xarray"}


def _resolve(dotted: str, module: str | None, klass: str | None) -> bool:
    """Whether ``dotted`` names a Python object seen from ``module`` (and ``klass``):
    a module attribute path, a sarcomere object or a builtin."""
    target = dotted.lstrip(".~")
    head, _, rest = target.partition(".")
    if head in ALIASES:  # an annotation under TYPE_CHECKING: ``ca.SX``
        target = f"{ALIASES[head]}.{rest}"
    scopes = []
    if module:
        parts = module.split(".")
        if klass:
            scopes.append(f"{module}.{klass}")
        scopes += [".".join(parts[:i]) for i in range(len(parts), 1, -1)]
    scopes += ["", "sarcomere", "builtins"]
    for scope in scopes:
        full = f"{scope}.{target}" if scope else target
        if _lookup(full):
            return True
    # The page's module is the public home, not the defining module: a docstring's
    # ``ca.SX`` or ``Trajectory`` is found in a library module's namespace.
    for name, mod in list(sys.modules.items()):
        if name.startswith("sarcomere.") and _attrs(mod, target.split(".")):
            return True
    return hasattr(builtins, target)


def _attrs(obj: object, names: list[str]) -> bool:
    for i, name in enumerate(names):
        if hasattr(obj, name):
            obj = getattr(obj, name)
        else:  # an instance attribute of a class, set in a method, is a leaf
            return i == len(names) - 1 and _instance_attribute(obj, name)
    return True


def _instance_attribute(obj: object, name: str) -> bool:
    if not isinstance(obj, type):
        return False
    assigned = re.compile(rf"\bself\.{re.escape(name)}\s*(:[^=]*)?=[^=]")
    for klass in obj.__mro__:
        if name in vars(klass).get("__annotations__", {}):
            return True
        try:
            if assigned.search(inspect.getsource(klass)):
                return True
        except (OSError, TypeError):
            continue
    return False


def _lookup(full: str) -> bool:
    parts = full.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = import_module(".".join(parts[:cut]))
        except (ImportError, ValueError, TypeError):
            continue
        return _attrs(obj, parts[cut:])
    return False


def missing_reference(app, env, node, contnode):
    """A cross reference to an existing object outside the reference (a private base, a
    module's helper, numpy, CasADi: no inventory is fetched) renders as code; a reference
    to nothing (a renamed or deleted name) stays a warning, an error under ``-W``."""
    if node.get("refdomain") != "py":
        return None
    target, module, klass = node["reftarget"], node.get("py:module"), node.get("py:class")
    if _resolve(target, module, klass) or (
        node.get("reftype") in ("meth", "attr") and _some_method(target)
    ):
        return contnode
    return None


def _some_method(name: str) -> bool:
    """An autosummary line loses its class: ``:meth:`refuse``` of some library class."""
    for module_name, module in list(sys.modules.items()):
        if module_name.startswith("sarcomere."):
            for value in list(vars(module).values()):
                if isinstance(value, type) and hasattr(value, name):
                    return True
    return False


def process_signature(app, what, name, obj, options, signature, return_annotation):
    """A dataclass field's ``default_factory`` shows as ``<factory>``, which is no Python
    and makes Sphinx split the signature at every comma: written ``...`` instead."""
    if signature and "<factory>" in signature:
        return signature.replace("<factory>", "..."), return_annotation
    return None


def process_docstring(app, what, name, obj, options, lines):
    """A public dict or tuple (``METHODS``, ``CONTROLLERS``) would show its type's
    docstring (``dict() -> new empty dictionary``): its ``#:`` comment instead, from the
    module that defines it."""
    if what not in ("data", "attribute") or isinstance(obj, type) or callable(obj):
        return
    own = inspect.getdoc(type(obj)) or ""
    if not own or "\n".join(lines).strip() != own.strip():
        return
    short = name.rsplit(".", 1)[-1]
    lines[:] = []
    for module_name, module in sorted(sys.modules.items()):
        if module_name.startswith("sarcomere.") and vars(module).get(short) is obj:
            comment = ModuleAnalyzer.for_module(module_name).find_attr_docs().get(("", short))
            if comment:
                lines[:] = list(comment)
                return


def setup(app):
    landing.draw(HERE / "_generated" / "landing-step-50g.png")
    app.connect("autodoc-process-docstring", process_docstring)
    app.connect("autodoc-process-signature", process_signature)
    apigen.write_api(HERE / "api")
    app.connect("missing-reference", missing_reference, priority=900)
