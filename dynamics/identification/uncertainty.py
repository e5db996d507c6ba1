"""Uncertainty and identifiability at an optimum: sensitivities, Fisher covariance,
correlations, the singular values of the weighted sensitivity matrix, profile
likelihoods and a verdict per parameter.

Sensitivities are total derivatives of the weighted residuals ``r_w`` with respect to
the search variables ``phi`` along the constraints ``g(v) = 0`` (implicit function
theorem on the exact sparse Jacobians): ``S = dr_w/dphi - dr_w/ds (dg/ds)^-1 dg/dphi``.
The Fisher information is ``F = S^T S`` (weights ``1/sd``: with estimated noise levels the
ML ones), its inverse the covariance of ``phi``; the covariance of the values follows by
``d theta / d phi`` (``theta`` for log-scaled ones). Fisher intervals are
``phi +- 1.96 sd(phi)`` mapped to values (so a log-scaled interval stays positive).

Verdicts (docs/fitting.md): **structurally non-identifiable** where a singular value of
``S`` is below :data:`FLAT` of the largest and the parameter takes part in its singular
vector (above :data:`TAKES_PART`): the data determine only a combination; **practically
non-identifiable** where its profile does not rise by the 95 % chi-squared threshold
(:data:`CHI2_95`, 1 degree of freedom) before a bound on one side, or rises there only
while a parameter correlated with it beyond :data:`COUPLED` sits on one of its bounds
(the bound, not the data, closes the valley); **identifiable** otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from .problem import Problem, Solution

CHI2_95 = 3.841458820694124
"""The 95 % quantile of chi-squared with one degree of freedom."""

Z_95 = 1.959963984540054
"""The two-sided 95 % quantile of the standard normal."""

FLAT = 1e-6
"""A singular value of ``S`` below this fraction of the largest is a flat direction."""

TAKES_PART = 0.2
"""A parameter takes part in a flat direction where its share of the (unit) singular
vector exceeds this."""

COUPLED = 0.9
"""A profile's crossing does not count where a parameter whose Fisher correlation with
the profiled one exceeds this (in magnitude) is on a bound at the crossing point."""

ON_BOUND = 1e-6
"""A search variable within this of a bound is on it."""


def sensitivities(problem: Problem, sol: Solution) -> np.ndarray:
    """``S = d r_w / d phi`` along the constraints (rows: residuals, columns: parameters)."""
    lin = problem.linearize(sol.v, sol.weights)
    n = len(problem.params)
    Jr, Jg = lin.Jr, lin.Jg
    S = Jr[:, :n].toarray()
    if Jg.shape[0]:
        X = spla.splu(Jg[:, n:].tocsc()).solve(Jg[:, :n].toarray())
        S = S - Jr[:, n:] @ X
    return np.asarray(S)


@dataclass
class Fisher:
    """Fisher information of ``phi``, covariance and correlation of the values, standard
    deviations, 95 % Fisher intervals (values), singular values of ``S`` and the flat
    directions (unit vectors in ``phi``)."""

    S: np.ndarray
    information: np.ndarray
    covariance: np.ndarray
    sd: np.ndarray
    sd_phi: np.ndarray
    correlation: np.ndarray
    interval: np.ndarray
    singular_values: np.ndarray
    flat: list[np.ndarray] = field(default_factory=list)


def fisher(problem: Problem, sol: Solution, S: np.ndarray | None = None) -> Fisher:
    """The :class:`Fisher` record at ``sol`` (``S``: the sensitivities if known)."""
    S = sensitivities(problem, sol) if S is None else S
    n = S.shape[1]
    # V n x n: full matrices only with fewer residuals than parameters (the missing
    # singular values are 0); else U stays thin (a full U of fit-synthetic's 6013 rows
    # took 0.7 s of the 0.8 s of this function)
    wide = S.shape[0] < n
    _, s, Vt = np.linalg.svd(S, full_matrices=wide) if S.size else (None, np.zeros(0), np.eye(n))
    s = np.concatenate([s, np.zeros(n - len(s))])
    top = s[0] if len(s) and s[0] > 0 else 1.0
    keep = s > FLAT * top
    flat = [Vt[i] for i in range(n) if not keep[i]]
    cov_phi = (Vt[keep].T / s[keep] ** 2) @ Vt[keep]
    sd_phi = np.sqrt(np.maximum(np.diag(cov_phi), 0.0))
    for direction in flat:  # a flat direction: unbounded variance for its parameters
        sd_phi[np.abs(direction) > TAKES_PART] = np.inf
    D = np.array([e.dtheta_dphi(t) for e, t in zip(problem.params, sol.theta, strict=True)])
    cov = cov_phi * np.outer(D, D)
    sd = np.abs(D) * sd_phi
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_phi / np.outer(sd_phi, sd_phi)
    corr[~np.isfinite(corr)] = np.nan
    np.fill_diagonal(corr, 1.0)
    lo = [
        e.to_theta(float(p - Z_95 * d))
        for e, p, d in zip(problem.params, sol.phi, sd_phi, strict=True)
    ]
    hi = [
        e.to_theta(float(p + Z_95 * d))
        for e, p, d in zip(problem.params, sol.phi, sd_phi, strict=True)
    ]
    interval = np.column_stack([lo, hi]) if n else np.zeros((0, 2))
    return Fisher(S, S.T @ S, cov, sd, sd_phi, corr, interval, s, flat)


def combination(names: list[str], direction: np.ndarray, log: list[bool]) -> str:
    """A flat direction in words: ``a^+1.00 * b^-1.00`` (log-scaled) or ``+1.00 a -1.00 b``,
    normalised to its largest entry; moving along it leaves the fit unchanged."""
    d = direction / direction[np.argmax(np.abs(direction))]
    parts = [(n, c, lg) for n, c, lg in zip(names, d, log, strict=True) if abs(c) > 1e-3]
    if all(lg for _, _, lg in parts):
        return " * ".join(f"{n}^{c:+.2f}" for n, c, _ in parts)
    return " ".join(f"{c:+.2f} {n}" for n, c, _ in parts)


@dataclass
class Profile:
    """A profile likelihood: values (SI) and the rise of the cost ``chi2 - chi2_min``
    (sorted by value), the 95 % interval ends (None: the bound came first, an open
    side), solves that failed, and per side the other parameters (indices) on a bound
    at the point where the profile crossed."""

    values: list[float]
    rise: list[float]
    low: float | None
    high: float | None
    failed: int = 0
    on_bounds: tuple[tuple[int, ...], tuple[int, ...]] = ((), ())

    @property
    def crosses(self) -> bool:
        return self.low is not None and self.high is not None


def profile(
    problem: Problem,
    sol: Solution,
    k: int,
    sd_phi: float,
    threshold: float = CHI2_95,
    max_points: int = 12,
) -> Profile:
    """The profile of parameter ``k``: the others re-optimised with ``phi_k`` held, stepping
    out from the optimum in both directions until the cost has risen by ``threshold`` or a
    bound is reached; the interval ends by interpolating the crossing linearly in the
    square root of the rise (exact for a quadratic profile: linear in the rise itself put
    the end of a well-determined parameter, reached in one step of 3.4 sd, at 1.1 sd
    instead of 1.96)."""
    e = problem.params[k]
    lo, hi = e.to_phi(e.low), e.to_phi(e.high)
    first = 0.5 * sd_phi if np.isfinite(sd_phi) and sd_phi > 0 else 0.1
    first = float(np.clip(first, 1e-9 * max(1.0, abs(hi - lo)), 0.5))
    values, rises, ends, failed, pinned = [sol.phi[k]], [0.0], [], 0, []
    for sign in (-1.0, 1.0):
        step, last_phi, last_rise, v = first, float(sol.phi[k]), 0.0, sol.v
        end, held = None, ()
        for _ in range(max_points):
            target = float(np.clip(last_phi + sign * step, lo, hi))
            if target == last_phi:
                break
            s = problem.solve(v, sol.weights, fixed={k: target})
            if not s.success:
                failed += 1
                step /= 2
                continue
            rise = max(s.cost - sol.cost, 0.0)
            values.append(target)
            rises.append(rise)
            if rise >= threshold:  # interpolated in the signed root (exact if quadratic)
                a, b = np.sqrt(last_rise), np.sqrt(rise)
                end = last_phi + (np.sqrt(threshold) - a) / (b - a) * (target - last_phi)
                held = _on_bounds(problem, s.phi, k)
                break
            # aim the next step at the threshold (a quadratic profile), within x0.5..x3
            grow = np.sqrt(threshold / max(rise, 1e-12)) if rise > 0 else 3.0
            step = abs(target - sol.phi[k]) * float(np.clip(grow, 1.5, 3.0)) - abs(
                target - sol.phi[k]
            )
            step = max(step, first)
            last_phi, last_rise, v = target, rise, s.v
            if target in (lo, hi):
                break
        ends.append(None if end is None else float(e.to_theta(float(end))))
        pinned.append(held)
    order = np.argsort(values)
    vals = [float(e.to_theta(float(values[i]))) for i in order]
    rise_sorted = [float(rises[i]) for i in order]
    return Profile(vals, rise_sorted, ends[0], ends[1], failed, (pinned[0], pinned[1]))


def _on_bounds(problem: Problem, phi: np.ndarray, k: int) -> tuple[int, ...]:
    """The parameters other than ``k`` whose search variable is on a bound."""
    n = len(problem.params)
    lo, hi = (b[:n] for b in problem.bounds())
    near = np.minimum(phi[:n] - lo, hi - phi[:n]) <= ON_BOUND * np.maximum(1.0, hi - lo)
    return tuple(int(j) for j in np.flatnonzero(near) if j != k)


def verdicts(problem: Problem, fis: Fisher, profiles: dict[int, Profile] | None) -> list[dict]:
    """Per parameter: ``verdict`` (identifiable, practically non-identifiable,
    structurally non-identifiable) and ``why``."""
    names = [e.name for e in problem.params]
    log = [e.log for e in problem.params]
    out = []
    for k in range(len(names)):
        flats = [d for d in fis.flat if abs(d[k]) > TAKES_PART]
        if flats:
            combo = combination(names, flats[0], log)
            out.append(
                {
                    "verdict": "structurally non-identifiable",
                    "why": f"a flat direction of the weighted sensitivities: {combo} can change "
                    "without changing any prediction (only the complementary combination is "
                    "determined)",
                }
            )
            continue
        prof = (profiles or {}).get(k)
        held = _held_by(prof, fis, k) if prof is not None and prof.crosses else []
        if held:
            sides = " and ".join(side for side, _ in held)
            j = held[0][1]
            out.append(
                {
                    "verdict": "practically non-identifiable",
                    "why": f"on the {sides} side the profile reaches the 95 % threshold only "
                    f"with {names[j]} (correlation {fis.correlation[k, j]:+.4f}) on a bound: "
                    "the bound, not the data, closes the valley",
                }
            )
            continue
        if prof is not None and not prof.crosses:
            side = "lower" if prof.low is None else "upper"
            out.append(
                {
                    "verdict": "practically non-identifiable",
                    "why": f"the profile stays below the 95 % threshold (+{CHI2_95:.2f}) up to the "
                    f"{side} bound",
                }
            )
            continue
        out.append(
            {
                "verdict": "identifiable",
                "why": "the profile crosses the 95 % threshold on both sides"
                if prof is not None
                else "Fisher information non-singular (no profile computed)",
            }
        )
    return out


def _held_by(prof: Profile, fis: Fisher, k: int) -> list[tuple[str, int]]:
    """The sides (and a parameter) where the crossing came with a parameter correlated
    with ``k`` beyond :data:`COUPLED` on a bound."""
    out = []
    for side, held in zip(("lower", "upper"), prof.on_bounds, strict=True):
        coupled = [j for j in held if abs(fis.correlation[k, j]) > COUPLED]
        if coupled:
            out.append((side, coupled[0]))
    return out


__all__ = ["CHI2_95", "Fisher", "Profile", "fisher", "profile", "sensitivities", "verdicts"]
