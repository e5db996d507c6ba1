"""The stability guard of explicit fixed-step methods: the largest stable step estimated
from the Jacobian's eigenvalues before a run (see :func:`stability_limit`)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..equilibrium import solve_equilibrium
from ..errors import ParameterError, SarcomereError
from ..modeling.model import Model


class StepStabilityWarning(UserWarning):
    """A fixed explicit step exceeds the estimated linear stability limit."""


# --- stability of explicit schemes ------------------------------------------------------
@dataclass(frozen=True)
class ExplicitScheme:
    """An explicit Runge-Kutta tableau and its stability polynomial.

    Attributes
    ----------
    name : str
        Method name.
    A : tuple of tuple of float
        Strictly lower triangular stage matrix.
    b, c : tuple of float
        Weights and stage times (fractions of the step).
    poly : tuple of float
        Coefficients of ``R(z) = sum_k poly[k] z^k`` (``y_{n+1} = R(h lambda) y_n``).
    """

    name: str
    A: tuple
    b: tuple
    c: tuple
    poly: tuple


RK4 = ExplicitScheme(
    "rk4",
    ((0, 0, 0, 0), (0.5, 0, 0, 0), (0, 0.5, 0, 0), (0, 0, 1, 0)),
    (1 / 6, 1 / 3, 1 / 3, 1 / 6),
    (0, 0.5, 0.5, 1),
    (1, 1, 1 / 2, 1 / 6, 1 / 24),
)
EULER = ExplicitScheme("euler", ((0,),), (1,), (0,), (1, 1))
SCHEMES = {"rk4": RK4, "euler": EULER}


def stability_radius(poly: tuple, theta: np.ndarray) -> np.ndarray:
    """Distance from 0 to the boundary of the stability region along rays.

    The region is ``|R(z)| <= 1`` with ``R(z) = sum_k poly[k] z^k``. Along the ray
    ``z = r exp(i theta)`` the radius is the first ``r > 0`` where ``|R| = 1``
    (grid scan, then Brent's method to 1e-12). For RK4 on the negative real axis it
    is 2.7853; on the imaginary axis 2 sqrt(2); for explicit Euler ``-2 cos(theta)``.

    Parameters
    ----------
    poly : tuple of float
        Stability polynomial coefficients, lowest order first.
    theta : array_like
        Ray angles [rad], ``pi/2 <= |theta| <= pi`` (the left half-plane).

    Returns
    -------
    numpy.ndarray
        Radii [1] (0 where the ray leaves the region at once).
    """
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    coeffs = np.asarray(poly, dtype=float)[::-1]
    r_max = 2.0 * len(poly) + 2.0
    r = np.linspace(0.0, r_max, 4001)[1:]

    def excess(rr: float | np.ndarray, th: float) -> float | np.ndarray:
        return np.abs(np.polyval(coeffs, rr * np.exp(1j * th))) ** 2 - 1.0

    out = np.empty_like(theta)
    for i, th in enumerate(theta):
        g = excess(r, th)
        outside = np.flatnonzero(g > 0)
        if len(outside) == 0:
            out[i] = r_max
        elif outside[0] == 0:
            out[i] = 0.0
        else:
            k = outside[0]
            from scipy.optimize import brentq  # here: a run without rk4/euler never needs it

            out[i] = brentq(excess, r[k - 1], r[k], args=(th,), xtol=1e-12)
    return out


def max_stable_step(eigenvalues: np.ndarray, scheme: ExplicitScheme) -> tuple[float, complex]:
    """Largest step [s] with every ``h lambda`` in the scheme's stability region.

    ``h_max = min over lambda of r(arg lambda) / |lambda|`` (:func:`stability_radius`).
    Eigenvalues with a positive real part (a physical instability) or zero are left
    out: no step size makes those decay.

    Returns
    -------
    (float, complex)
        The limit [s] (``inf`` if no eigenvalue limits it) and the eigenvalue
        [1/s] that sets it.
    """
    lam = np.asarray(eigenvalues, dtype=complex)
    mag = np.abs(lam)
    keep = (lam.real <= 0) & (mag > 1e-9 * max(float(mag.max(initial=0.0)), 1.0))
    if not keep.any():
        return math.inf, complex(0.0)
    lam = lam[keep]
    h = stability_radius(scheme.poly, np.angle(lam)) / np.abs(lam)
    k = int(np.argmin(h))
    return float(h[k]), complex(lam[k])


def jacobian_eigenvalues(model: Model, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Eigenvalues [1/s] of ``A = d ode / dx`` at one point (explicit ODE)."""
    A = np.array(model.function("jac")(x, model.z0(), u, p)[0])
    return np.linalg.eigvals(A)


def stability_limit(
    model: Model,
    scheme: ExplicitScheme,
    x0: np.ndarray,
    u0: np.ndarray,
    t_after: float,
    u_after: np.ndarray,
    p: np.ndarray,
) -> tuple[float, complex, str]:
    """Stability limit of ``scheme`` estimated before a run.

    Two points are checked: the initial state ``x0`` with the input ``u0``, and the
    equilibrium that the input ``u_after`` (the input just after the first breakpoint,
    at ``t_after``, or at the end if there is none) leads to (skipped when no
    equilibrium is found). The second catches models that are stiffest at the new
    operating point (e.g. a wider laminar region, ``r_lam = 0.995``); points in between
    are not checked (:mod:`sarcomere.dynamics.studies.stability` scans a whole trajectory).

    Returns
    -------
    (float, complex, str)
        Limit [s], the eigenvalue [1/s] that sets it, and where it was found.
    """
    m = model
    points = [("the initial state", x0, u0)]
    try:
        eq = solve_equilibrium(
            m,
            dict(zip(m.input_names, np.asarray(u_after).tolist(), strict=True)),
            params=dict(zip(m.param_names, p.tolist(), strict=True)),
        )
        points.append((f"the equilibrium for the input at t = {t_after:.4g} s", eq.x, u_after))
    except SarcomereError:
        pass
    best = (math.inf, complex(0.0), points[0][0])
    for where, x, u in points:
        h, crit = max_stable_step(jacobian_eigenvalues(m, x, u, p), scheme)
        if h < best[0]:
            best = (h, crit, where)
    return best


def on_unstable(options: dict) -> str:
    """The validated ``on_unstable`` action: "warn", "raise" or "ignore"."""
    action = options["on_unstable"]
    if action not in ("warn", "raise", "ignore"):
        raise ParameterError("solver.options.on_unstable", action, "'warn', 'raise' or 'ignore'")
    return action


def check_step(
    scheme: ExplicitScheme, h_used: float, action: str, limit: tuple[float, complex, str]
) -> None:
    """Warn (or raise, per ``action``) when the step ``h_used`` [s] exceeds ``limit``
    (from :func:`stability_limit`)."""
    h_max, lam, where = limit
    if action == "ignore" or h_used <= h_max:
        return
    theta = float(np.degrees(np.angle(lam)))
    why = (
        f"{scheme.name} step {h_used:.4g} s exceeds the linear stability limit "
        f"{h_max:.4g} s = r(theta)/|lambda| set by the Jacobian eigenvalue "
        f"{lam.real:.4g}{lam.imag:+.4g}j 1/s (theta = {theta:.1f} deg) at {where}; "
        "the answer may blow up or settle into a false oscillation"
    )
    if action == "raise":
        raise ParameterError("solver.step", h_used, f"(0, {h_max:.4g}] s", why)
    warnings.warn(why + " (options=(('on_unstable', 'raise'),) refuses)", StepStabilityWarning, 4)
