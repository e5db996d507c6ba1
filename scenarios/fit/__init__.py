"""Fit files: parameter identification from measured data (docs/fitting.md).

``Fit.from_file(path).run(out)`` (:mod:`.run`); the file (:mod:`.spec`), its data
(:mod:`.data`), binding to the model (:mod:`.build`), metrics (:mod:`.validation`),
files and plots (:mod:`.report`, :mod:`.plots`) and ``sarcomere fit`` (:mod:`.command`).
"""

from sarcomere.dynamics.lazy import lazy_exports

_HOMES = {"Fit": "run", "FitResult": "run", "FitError": "spec", "load_fit": "spec"}
__all__ = list(_HOMES)
__getattr__, __dir__ = lazy_exports(__name__, _HOMES, __all__)
