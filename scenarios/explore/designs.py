"""Sample points of a study: grids, Latin hypercube, scrambled Sobol', Monte Carlo, and
SALib's Saltelli and Morris designs; and the calibration family as a discrete factor.

Continuous factors are drawn on the unit cube and mapped through each factor's inverse
CDF (uniform, normal, lognormal), so Latin hypercube and Sobol' points keep their
stratification under any of the three; discrete factors (``levels``) take
``levels[floor(u k)]``. Every design is a pure function of the study and its seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Design method of each study: the grid, ``[study.sample] method`` or the sensitivity
#: method's SALib design.
METHODS = ("grid", "lhs", "sobol", "montecarlo", "sobol-saltelli", "morris")


@dataclass(frozen=True)
class FamilyMember:
    """One member of the calibration family (docs/model.md, "Choice of L_r"): a
    restoring-element length ``L_r`` [m] and the ``A_p`` [m^2], ``A_r`` [m^2], ``k_s``
    [N/m] that meet the paper's three calibration targets with it."""

    L_r: float
    A_p: float
    A_r: float
    k_s: float


#: The calibration family at :data:`sarcomere.dynamics.calibration.FAMILY_L_R`, from
#: ``calibration.calibrate(replace(APSParams.from_paper(), L_r=L_r))`` (each member meets
#: the three targets; tests/scenarios/explore/test_designs.py checks it to 1e-6).
FAMILY = (
    FamilyMember(4e-3, 3.207915945957384e-06, 1.7352214541840588e-07, 307.5641976171445),
    FamilyMember(8e-3, 3.0461546729239203e-06, 3.907191092890234e-07, 391.66838831815386),
    FamilyMember(16e-3, 2.7246744333892797e-06, 6.419758315832829e-07, 585.7859901959248),
    FamilyMember(20e-3, 2.6238311296131044e-06, 7.370611992546922e-07, 694.0039164572522),
    FamilyMember(34e-3, 2.437827205448019e-06, 1.046939296307396e-06, 1078.03681276681),
)


def family_member(L_r: float) -> dict[str, float]:
    """The APS fields of the family member with restoring length ``L_r`` [m]."""
    for m in FAMILY:
        if np.isclose(m.L_r, L_r, rtol=1e-9, atol=0):
            return {"L_r": m.L_r, "A_p": m.A_p, "A_r": m.A_r, "k_s": m.k_s}
    have = ", ".join(f"{m.L_r * 1e3:g} mm" for m in FAMILY)
    raise KeyError(f"no calibration family member with L_r = {L_r:g} m (members: {have})")


@dataclass(frozen=True)
class Design:
    """The samples of a study.

    points : (n_samples, n_factors) float64, SI (discrete factors as their value)
    factor_names : names in column order
    grid_shape : the grid's shape (C order of the factors) or None
    salib_problem : SALib's problem dict (sensitivity) or None
    method : one of :data:`METHODS`
    salib_options : the sampler options the analysis must repeat (``calc_second_order``
        for Sobol', ``num_levels`` for Morris), empty otherwise
    """

    points: np.ndarray
    factor_names: tuple[str, ...]
    grid_shape: tuple[int, ...] | None
    salib_problem: dict | None
    method: str
    salib_options: dict

    @property
    def n_samples(self) -> int:
        return self.points.shape[0]


def sample_count(kind: str, method: str, n_factors: int, options: dict) -> int:
    """Samples a design will have, computed before making it (the size check)."""
    if kind == "grid":
        return int(np.prod(options["grid_shape"]))
    if method == "sobol-saltelli":
        per = 2 * n_factors + 2 if options["calc_second_order"] else n_factors + 2
        return options["base_count"] * per
    if method == "morris":
        return options["base_count"] * (n_factors + 1)
    return options["count"]


def make_design(study) -> Design:
    """The design of a checked :class:`~.spec.StudyDef`."""
    opts = dict(study.options)
    names = study.factor_names
    if study.kind == "grid":
        points = grid_points([f.values for f in study.factors])
        return Design(points, names, tuple(len(f.values) for f in study.factors), None, "grid", {})
    if study.kind == "sample":
        u = unit_cube(study.method, len(names), opts["count"], study.seed)
        return Design(to_factors(u, study.factors), names, None, None, study.method, {})
    problem = salib_problem(study.factors)
    if study.method == "sobol-saltelli":
        from SALib.sample import sobol

        second = bool(opts["calc_second_order"])
        points = sobol.sample(
            problem, opts["base_count"], calc_second_order=second, seed=study.seed
        )
        return Design(points, names, None, problem, study.method, {"calc_second_order": second})
    from SALib.sample import morris

    points = morris.sample(problem, opts["base_count"], num_levels=opts["levels"], seed=study.seed)
    return Design(points, names, None, problem, "morris", {"num_levels": opts["levels"]})


def grid_points(axes) -> np.ndarray:
    """Full factorial of ``axes`` (sequences of values), C order: the last axis fastest."""
    mesh = np.meshgrid(*[np.asarray(a, float) for a in axes], indexing="ij")
    return np.stack([m.reshape(-1) for m in mesh], axis=1)


def unit_cube(method: str, d: int, count: int, seed: int) -> np.ndarray:
    """``count`` points in [0, 1)^d: Latin hypercube, scrambled Sobol' or plain Monte
    Carlo, seeded."""
    from scipy.stats import qmc

    rng = np.random.default_rng(seed)
    if method == "lhs":
        return qmc.LatinHypercube(d, seed=rng).random(count)
    if method == "sobol":
        return qmc.Sobol(d, scramble=True, seed=rng).random(count)
    return rng.random((count, d))


def to_factors(u: np.ndarray, factors) -> np.ndarray:
    """Map unit-cube points column by column through each factor's inverse CDF."""
    from scipy.stats import norm

    out = np.empty_like(u)
    for j, f in enumerate(factors):
        col = u[:, j]
        if f.values:
            k = len(f.values)
            out[:, j] = np.asarray(f.values)[np.minimum((col * k).astype(int), k - 1)]
        elif f.dist == "uniform":
            out[:, j] = f.args[0] + col * (f.args[1] - f.args[0])
        elif f.dist == "normal":
            out[:, j] = f.args[0] + f.args[1] * norm.ppf(col)
        else:
            out[:, j] = f.args[0] * np.exp(f.args[1] * norm.ppf(col))
    return out


def salib_problem(factors) -> dict:
    """SALib's problem dict: names, bounds and distributions (``unif`` [low, high],
    ``norm`` [mean, std], ``lognorm`` [ln median, sigma])."""
    dists, bounds = [], []
    for f in factors:
        if f.dist == "uniform":
            dists.append("unif")
            bounds.append([f.args[0], f.args[1]])
        elif f.dist == "normal":
            dists.append("norm")
            bounds.append([f.args[0], f.args[1]])
        else:
            dists.append("lognorm")
            bounds.append([float(np.log(f.args[0])), f.args[1]])
    return {
        "num_vars": len(factors),
        "names": [f.name for f in factors],
        "bounds": bounds,
        "dists": dists,
    }
