"""How well a model reproduces an experiment, per measured signal: RMSE, the normalised
RMSE ``|y - y_hat| / |y - mean(y)|`` and the fit ``100 (1 - NRMSE)`` % (as system
identification tools report it), and for a time series the Ljung-Box test of the
residuals' whiteness (lags ``min(20, n / 5)``; white when ``p >= 0.05``: a misfit with
structure, e.g. a missing time constant, shows as non-white residuals)."""

from __future__ import annotations

import numpy as np

from sarcomere.dynamics.identification.problem import Problem, Solution

WHITE_P = 0.05
"""Residuals are called white when the Ljung-Box p-value is at least this."""


def ljung_box(e: np.ndarray, lags: int | None = None) -> tuple[float, float, int]:
    """Ljung-Box ``Q``, its p-value (chi-squared with ``lags`` degrees of freedom) and the
    lags: ``Q = n (n + 2) sum_k rho_k^2 / (n - k)``."""
    e = np.asarray(e, dtype=float) - np.mean(e)
    n = len(e)
    h = lags or max(1, min(20, n // 5))
    denom = float(e @ e)
    if n < 3 or denom == 0:
        return 0.0, 1.0, h
    from scipy import stats  # here: its import (0.6 s of CPU) serves time series only

    rho = np.array([float(e[k:] @ e[:-k]) / denom for k in range(1, h + 1)])
    q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, h + 1))))
    return q, float(stats.chi2.sf(q, h)), h


def experiment_metrics(problem: Problem, sol: Solution) -> dict[str, dict]:
    """Per experiment (static points by their experiment), per signal: ``n``, ``rmse``
    (SI), ``nrmse``, ``fit_percent``, and for time series ``ljung_box_q``, ``p``,
    ``white``; with the data and predictions for the plots."""
    rows = problem.rows
    exp_of = np.array([e.split("#", 1)[0].split(":", 1)[0] for e in rows.experiment])
    sig = np.array(rows.signal)
    pred = problem.predictions(sol)
    series = {s.name for s in problem.series}
    out: dict[str, dict] = {}
    for exp in dict.fromkeys(exp_of):
        out[exp] = {}
        for s in dict.fromkeys(sig[exp_of == exp]):
            mask = (exp_of == exp) & (sig == s)
            y, yh = rows.data[mask], pred[mask]
            e = y - yh
            spread = float(np.linalg.norm(y - y.mean()))
            nrmse = float(np.linalg.norm(e) / spread) if spread > 0 else float("nan")
            rec = {
                "n": int(mask.sum()),
                "rmse": float(np.sqrt(np.mean(e**2))),
                "nrmse": nrmse,
                "fit_percent": 100.0 * (1.0 - nrmse),
                "data": y.tolist(),
                "prediction": yh.tolist(),
                "sample": np.array(rows.sample)[mask].tolist(),
            }
            if exp in series:
                q, p, h = ljung_box(e)
                rec.update(ljung_box_q=q, ljung_box_p=p, lags=h, white=bool(p >= WHITE_P))
            out[exp][s] = rec
    return out
