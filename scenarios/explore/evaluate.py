"""Run a batch of a study's samples in this process: apply each sample's factor values to
the base scene, simulate with the scene's solver from the start equilibrium, reduce to
metrics.

A sample that fails (a solver error, a value the model refuses, CasADi's RuntimeError) is
recorded with status 1 and its one-line message and never stops the batch; a programming
error (TypeError, KeyError, ...) is not a sample's failure and propagates. Models are
flattened once per process and structure (:func:`~.factors.model_for`), compiled
``radau`` code is loaded once per model; the scene is bound once per process and study
(:func:`context`).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np

from sarcomere.dynamics.errors import SarcomereError

from . import metrics as mx
from .spec import StudyDef


@dataclass
class BatchResult:
    """Results of a batch, in the order of ``indices``.

    metrics : name -> float64[len]; series : signal -> float64[len, T] (or empty);
    series_time : float64[T] or None; status : int8[len] (0 ok, 1 failed); error : the
    failure's message, or for a sample that ran, why a metric is NaN ("" when none is);
    timing : seconds spent integrating (solve_equilibrium + simulate) and in total.
    """

    indices: np.ndarray
    metrics: dict[str, np.ndarray]
    series: dict[str, np.ndarray]
    series_time: np.ndarray | None
    status: np.ndarray
    error: list[str]
    timing: dict[str, float] = field(default_factory=dict)


class _Context:
    """A study bound in this process: its scene, and its design when first needed."""

    def __init__(self, study: StudyDef) -> None:
        from .factors import scene_context

        self.study = study
        self.scene = scene_context(study.scene())
        self._design = None

    @property
    def design(self):
        if self._design is None:
            self._design = self.study.design()
        return self._design


def context(study: StudyDef) -> _Context:
    """The bound scene (and design) of ``study``, once per process (the latest few)."""
    from .factors import Keyed

    return _context(Keyed((study.fingerprint(),), study))


@functools.lru_cache(maxsize=4)
def _context(study) -> _Context:
    return _Context(study.value)


def evaluate_batch(study: StudyDef, indices, points: np.ndarray | None = None) -> BatchResult:
    """Simulate the samples ``indices`` of ``study``'s design (see the module docstring).

    ``points``: the batch's rows of ``study.design().points`` (n_indices x n_factors, SI),
    if the caller has them: the design (and SALib, scipy.stats) is then not made here.
    """
    tic = time.perf_counter()
    ctx = context(study)
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    k = len(idx)
    out = {m.name: np.full(k, np.nan) for m in study.metrics}
    series_time = None if study.series is None else np.asarray(study.series.time, float)
    series = {}
    if study.series is not None:
        series = {s: np.full((k, len(series_time)), np.nan) for s in study.series.signals}
    status = np.zeros(k, dtype=np.int8)
    errors = [""] * k
    solving = 0.0
    if points is None:
        rows = ctx.design.points[idx]
    else:
        rows = np.asarray(points, dtype=float).reshape(k, len(study.factors))
    for j, row in enumerate(rows):
        try:
            res, dt = _run(study, ctx, row)
            solving += dt
            values, notes = mx.compute(res, study.metrics)
            for name, v in values.items():
                out[name][j] = v
            if study.series is not None:
                for s, v in mx.series_values(res, study.series).items():
                    series[s][j] = v
            errors[j] = "; ".join(notes)
        except (SarcomereError, ValueError, ArithmeticError, RuntimeError) as exc:
            status[j] = 1
            errors[j] = _one_line(exc)
            for v in out.values():
                v[j] = np.nan
    timing = {"solve_s": solving, "total_s": time.perf_counter() - tic}
    return BatchResult(idx, out, series, series_time, status, errors, timing)


def _run(study: StudyDef, ctx: _Context, point):
    """One sample's Result (the signals the metrics need) and the seconds spent in the
    equilibrium and the integration (:func:`~sarcomere.scenarios.binding.run`, its start
    continued from the scene's own start equilibrium on this model, found once per model:
    most samples then need one Newton solve)."""
    from sarcomere.dynamics.equilibrium import solve_equilibrium

    from .. import binding

    sc = ctx.scene
    model, over, inputs = sc.apply(study.factors, point)
    tic = time.perf_counter()
    scene_u0 = {k: float(sig(sc.grid[0])) for k, sig in sc.inputs.items()}
    base_over = sc.binding.overrides
    key = ("explore.start", repr(sorted(scene_u0.items())), repr(sorted(base_over.items())))
    guess = model.cached(key, lambda: solve_equilibrium(model, scene_u0, base_over))
    settings = sc.settings if model is sc.model else binding.solver_settings(sc.scene, model)
    signals = mx.needed_signals(model.signal_names, study.metrics, study.series)
    res = binding.run(model, inputs, over, sc.grid, settings, signals, guess=guess)
    dt = time.perf_counter() - tic
    res.require_finite(sc.fidelity)
    return res, dt


def _one_line(exc: BaseException) -> str:
    """``Type: message`` on one line (at most 500 characters)."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}"[:500]
