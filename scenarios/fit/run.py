"""``Fit.from_file(path).run(out)``: multi-start, uncertainty, profiles, validation.

Starts: the fit file's start values, then scrambled Sobol' points inside the bounds (in
the search variables: log-uniform for log-scaled parameters), ``[fit] seed``. More than
:data:`LOCAL_STARTS` starts (or a ``scheduler``) run on Dask (the design studies' cluster:
an embedded local cluster, or the one at ``scheduler``), one start per task, and so do
the profiles, one parameter per task. A start whose initial simulation or solve fails is
dropped and counted; a start "reaches the best optimum" when its cost is within
:data:`SAME_OPTIMUM` (relative) of the best, and is "statistically the same" when its
chi-squared is within :data:`SAME_STATISTICALLY` of the best (along a flat valley the
first can be few while the second are all).
"""

from __future__ import annotations

import contextlib
import functools
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import SolverError
from sarcomere.dynamics.identification import uncertainty
from sarcomere.dynamics.identification.estimate import Fitted, fit_from
from sarcomere.dynamics.identification.problem import Solution

from .build import Built, build
from .design import ranking
from .spec import load_fit
from .validation import experiment_metrics

LOCAL_STARTS = 4
"""Up to this many starts (and their profiles) run in this process; more go to Dask."""

SAME_OPTIMUM = 1e-5
"""Relative cost difference within which a start counts as reaching the best optimum
(the solver stops at 1e-5 of the cost's predicted decrease: :class:`~sarcomere.dynamics.
identification.gauss_newton.Options`)."""

SAME_STATISTICALLY = 1.0
"""Chi-squared difference within which a start ends statistically at the best optimum
(far below the 3.84 of a 95 % interval)."""


@dataclass
class Start:
    """One start: its values (SI), the cost and status reached (or why it was dropped)."""

    theta0: list[float]
    theta: list[float] | None
    cost: float
    status: str
    dropped: bool


@dataclass
class FitResult:
    """What ``Fit.run`` returns: the built fit, the best solution and noise levels, the
    starts, the Fisher record, the profiles, verdicts, per-experiment metrics (fitted and
    held out), the wall time [s], the experiment ranking, the files written, and each
    time series' step grid at the fit (``Problem.grid_report``)."""

    built: Built
    solution: Solution
    sigma: dict[str, float]
    starts: list[Start]
    fisher: uncertainty.Fisher
    profiles: dict[int, uncertainty.Profile]
    verdicts: list[dict]
    metrics: dict[str, dict]
    validation: dict[str, dict]
    wall_time: float
    design: list[dict] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    grid: dict[str, dict] = field(default_factory=dict)

    @property
    def estimates(self) -> dict[str, tuple[float, str]]:
        """Parameter name -> (value, SI unit)."""
        return {
            e.name: (float(v), e.unit)
            for e, v in zip(self.built.params, self.solution.theta, strict=True)
        }

    @property
    def converged_starts(self) -> int:
        """Starts whose cost is within :data:`SAME_OPTIMUM` (relative) of the best."""
        best = self.solution.cost
        return sum(
            1
            for s in self.starts
            if not s.dropped and s.cost <= best + SAME_OPTIMUM * max(abs(best), 1.0)
        )

    @property
    def equivalent_starts(self) -> int:
        """Starts whose chi-squared is within :data:`SAME_STATISTICALLY` of the best."""
        best = self.solution.cost
        return sum(1 for s in self.starts if not s.dropped and s.cost <= best + SAME_STATISTICALLY)


class Fit:
    """A fit file, bound and checked (every bad input refused here, before any solve)."""

    def __init__(self, built: Built, path: str) -> None:
        self.built, self.path = built, path

    @classmethod
    def from_file(cls, path: str | Path) -> Fit:
        return cls(build(load_fit(path)), str(path))

    def start_points(self) -> np.ndarray:
        """The starts' values (SI): the start values, then scrambled Sobol' points."""
        params = self.built.params
        first = np.array([e.start for e in params])
        n = self.built.spec.starts
        if n == 1:
            return first[None, :]
        from scipy.stats import qmc

        with warnings.catch_warnings():  # any count of starts is allowed (the fit file's)
            warnings.filterwarnings("ignore", "The balance properties of Sobol", UserWarning)
            sobol = qmc.Sobol(len(params), scramble=True, seed=self.built.spec.seed)
            unit = sobol.random(n - 1)
        lo = np.array([e.to_phi(e.low) for e in params])
        hi = np.array([e.to_phi(e.high) for e in params])
        phi = lo + unit * (hi - lo)
        rest = np.array(
            [[e.to_theta(float(p)) for e, p in zip(params, row, strict=True)] for row in phi]
        )
        return np.vstack([first, rest])

    def run(
        self,
        out: str | Path | None = None,
        *,
        scheduler: str | None = None,
        workers: int | None = None,
        plots: bool = True,
        profiles: bool = True,
    ) -> FitResult:
        """Fit, estimate the uncertainty, validate; write ``out`` (all files or none) if
        given (:mod:`.report`). Raises SolverError when every start fails."""
        from ..outdir import check_out_dir

        folder = check_out_dir(out, "--out") if out is not None else None
        tic = time.perf_counter()
        points = self.start_points()
        distributed = scheduler is not None or len(points) > LOCAL_STARTS
        client_cm = _client(workers, scheduler) if distributed else None
        with client_cm if client_cm is not None else contextlib.nullcontext() as client:
            starts = self._starts(points, client)
            ok = [s for s in starts if not s.dropped]
            if not ok:
                why = "; ".join(sorted({s.status for s in starts}))[:400]
                raise SolverError(f"fit '{self.built.spec.name}': every start failed ({why})")
            best = min(ok, key=lambda s: s.cost)
            fitted = fit_from(self.built.problem, np.array(best.theta))
            sol = fitted.solution
            fis = uncertainty.fisher(self.built.problem, sol)
            profs = self._profiles(sol, fis, client) if profiles else {}
        result = FitResult(
            self.built,
            sol,
            fitted.sigma,
            starts,
            fis,
            profs,
            uncertainty.verdicts(self.built.problem, fis, profs if profiles else None),
            experiment_metrics(self.built.problem, sol),
            self._validation(fitted),
            0.0,
        )
        result.design = ranking(self.built, sol, fitted.sigma)
        result.grid = self.built.problem.grid_report(sol.theta)
        result.wall_time = time.perf_counter() - tic
        if folder is not None:
            from .report import write

            result.files = write(result, folder, plots=plots)
        return result

    def _starts(self, points: np.ndarray, client) -> list[Start]:
        if client is None:
            return [_one_start(self.built, theta) for theta in points]
        futures = client.map(_start_task, [self.path] * len(points), list(points), pure=False)
        return client.gather(futures)

    def _profiles(self, sol: Solution, fis, client) -> dict[int, uncertainty.Profile]:
        ks = range(len(self.built.params))
        if client is None:
            return {k: uncertainty.profile(self.built.problem, sol, k, fis.sd_phi[k]) for k in ks}
        futures = client.map(
            _profile_task,
            [self.path] * len(ks),
            [sol] * len(ks),
            list(ks),
            [float(fis.sd_phi[k]) for k in ks],
            pure=False,
        )
        return dict(zip(ks, client.gather(futures), strict=True))

    def _validation(self, fitted: Fitted) -> dict[str, dict]:
        prob = self.built.validation
        if prob is None:
            return {}
        try:
            v = prob.initial_guess(fitted.solution.theta)
        except SolverError as exc:
            return {"error": {"why": str(exc)}}
        # a prediction: the states simulated at the estimate, not re-fitted to the data
        return experiment_metrics(prob, prob.evaluate(v, prob.weights(fitted.sigma)))


def _one_start(built: Built, theta0: np.ndarray) -> Start:
    try:
        f = fit_from(built.problem, theta0)
    except SolverError as exc:
        return Start(list(map(float, theta0)), None, np.inf, f"dropped: {exc}", True)
    s = f.solution
    if not s.success:
        return Start(list(map(float, theta0)), None, np.inf, f"dropped: {s.status}", True)
    return Start(list(map(float, theta0)), s.theta.tolist(), s.cost, s.status, False)


@functools.lru_cache(maxsize=4)
def _cached(path: str) -> Built:
    return build(load_fit(path))


def _start_task(path: str, theta0: np.ndarray) -> Start:
    from ..threads import limited_blas

    with limited_blas():
        return _one_start(_cached(path), theta0)


def _profile_task(path: str, sol: Solution, k: int, sd_phi: float) -> uncertainty.Profile:
    from ..threads import limited_blas

    with limited_blas():
        return uncertainty.profile(_cached(path).problem, sol, k, sd_phi)


def _client(workers, scheduler):
    from ..explore.engine import cluster_client

    return cluster_client(workers, scheduler)
