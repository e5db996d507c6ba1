"""Reading and checking a study's factors (``[study.grid]``, ``[study.factors]``): each
name onto what it sets in the scene (:meth:`~.factors.SceneContext.target`), its values or
distribution in SI inside the allowed range, and the checks across factors (two that set
the same parameter, the family with an absolute APS field, a parameter missing at some
``n``). Every problem is a one-line error of the reader (a ``StudyError``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sarcomere.dynamics.errors import ParameterError

from ..spec import describe

DISTRIBUTIONS = ("uniform", "normal", "lognormal", "levels")

#: Any member's L_r (only its field names are used).
FAMILY_DEFAULT_L_R = 20e-3


@dataclass(frozen=True)
class Factor:
    """One input of a study, values in SI.

    Parameters
    ----------
    name : str
        ``n``, ``load``, ``pressure`` (or another input's name), ``family``,
        ``aps.<field>`` or a model parameter.
    unit : str
        SI unit of its values (``"1"`` for a relative factor).
    kind : str
        ``"continuous"`` or ``"discrete"`` (grid axes and ``levels`` are discrete).
    values : tuple of float
        Grid values or discrete levels (SI); empty for a continuous distribution.
    dist : str
        ``"uniform"``, ``"normal"``, ``"lognormal"``, or ``""`` (values).
    args : tuple of float
        uniform (low, high); normal (mean, std); lognormal (median, sigma of the log).
    relative : bool
        The value multiplies the base value (family member or scene) of the parameter.
    long_name : str
        A description for tables and plots.
    """

    name: str
    unit: str
    kind: str
    values: tuple[float, ...] = ()
    dist: str = ""
    args: tuple[float, ...] = ()
    relative: bool = False
    long_name: str = ""

    @property
    def bounds(self) -> tuple[float, float]:
        """Range of the values: the levels' extremes, a uniform's bounds, or the 0.1 % and
        99.9 % quantiles of a normal or lognormal (SI)."""
        if self.values:
            return min(self.values), max(self.values)
        if self.dist == "uniform":
            return self.args[0], self.args[1]
        z = 3.090232306167813  # standard normal 99.9 % quantile
        if self.dist == "normal":
            return self.args[0] - z * self.args[1], self.args[0] + z * self.args[1]
        return self.args[0] * math.exp(-z * self.args[1]), self.args[0] * math.exp(z * self.args[1])

    def definition(self) -> dict:
        """Canonical JSON-serialisable form."""
        return dataclasses.asdict(self)


def section(kind: str) -> str:
    """The table of ``[study]`` that holds the factors of a study of ``kind``."""
    return "grid" if kind == "grid" else "factors"


def target(r, path: tuple, name: str, ctx):
    """What factor ``name`` sets (a :class:`~.factors.Target`), or the reader's error."""
    try:
        return ctx.target(name)
    except ParameterError as exc:
        raise r.error(path, describe(exc)) from None


def read_values(r, raw, path: tuple, target) -> tuple[float, ...]:
    """Grid values or levels: a list of quantities, or {from, to, num} (inclusive)."""
    if target.category == "family" and raw == "all":
        return target.levels
    if isinstance(raw, dict):
        r.table(raw, path, ("from", "to", "num"), ("from", "to", "num"))
        lo, hi = (r.quantity(raw[k], (*path, k), target.unit) for k in ("from", "to"))
        num = r.integer(raw, path, "num", 2)
        values = tuple(float(v) for v in np.linspace(lo, hi, num))
    elif isinstance(raw, list) and raw:
        values = tuple(r.quantity(v, path, target.unit) for v in raw)
    else:
        raise r.error(path, f"{raw!r}: expected a list of values or {{from, to, num}}")
    if len(set(values)) != len(values):
        raise r.error(path, f"{raw!r}: the values repeat")
    for v in values:
        if not target.contains(v):
            raise r.error(path, target.refusal(v))
    return values


def read_grid(r, tbl, ctx) -> tuple[Factor, ...]:
    """The axes of ``[study.grid]``."""
    path = ("study", "grid")
    r.table(tbl, path)
    if not tbl:
        raise r.error(path, "give at least one axis")
    out = []
    for name, raw in tbl.items():
        t = target(r, (*path, name), name, ctx)
        _check_aps(r, (*path, name), t, ctx, discrete=True)
        values = read_values(r, raw, (*path, name), t)
        out.append(Factor(name, t.unit, "discrete", values, long_name=t.long_name))
    return tuple(out)


def read_factors(r, tbl, ctx, kind: str) -> tuple[Factor, ...]:
    """The factors of ``[study.factors]`` (kinds ``sample`` and ``sensitivity``)."""
    path = ("study", "factors")
    r.table(tbl, path)
    if not tbl:
        raise r.error(path, "give at least one factor")
    return tuple(_factor(r, name, item, (*path, name), ctx, kind) for name, item in tbl.items())


def _check_aps(r, path: tuple, target, ctx, discrete: bool) -> None:
    """Refuse an APS field that sets no parameter of the model (it would change nothing),
    or one that is not a run-time parameter (one model per value) drawn continuously."""
    if target.category != "aps":
        return
    b, field = ctx.binding, target.name.removeprefix("aps.")
    mapped = ctx.aps_parameters(field)
    where = f"fidelity '{ctx.fidelity}', thermal '{b.aps.thermal}'"
    if mapped == ():
        raise r.error(path, f"'{target.name}' sets no parameter of this model ({where})")
    if mapped is None and not discrete:
        raise r.error(
            path,
            f"'{target.name}' is not a run-time parameter of this model ({where}; its base "
            f"value {getattr(b.aps, field):g} {target.unit}): each value builds a model; "
            "give levels = [...]",
        )


def _factor(r, name: str, item, path: tuple, ctx, kind: str) -> Factor:
    t = target(r, path, name, ctx)
    r.table(item, path, (*DISTRIBUTIONS, "relative"))
    given = [d for d in DISTRIBUTIONS if d in item]
    if len(given) != 1:
        raise r.error(
            path, f"give exactly one of {', '.join(DISTRIBUTIONS)} (got {given or 'none'})"
        )
    dist = given[0]
    _check_aps(r, path, t, ctx, dist == "levels")
    relative = item.get("relative", False)
    if not isinstance(relative, bool):
        raise r.error((*path, "relative"), f"{relative!r}: expected true or false")
    if relative and t.category not in ("aps", "parameter"):
        raise r.error((*path, "relative"), f"'{name}' has no base value to scale; remove it")
    if t.category in ("n", "family") and dist != "levels":
        raise r.error((*path, dist), f"'{name}' takes discrete values: use levels = [...]")
    if kind == "sensitivity" and dist == "levels":
        raise r.error((*path, dist), "a sensitivity study needs continuous factors")
    unit = "1" if relative else t.unit
    check = relative_target(r, path, t, ctx) if relative else t
    where = (*path, dist)
    if dist == "levels":
        values = read_values(r, item[dist], where, check)
        return Factor(name, unit, "discrete", values, relative=relative, long_name=t.long_name)
    args = _distribution(r, dist, item[dist], where, unit, check)
    long_name = f"{t.long_name} (relative)" if relative else t.long_name
    return Factor(name, unit, "continuous", (), dist, args, relative, long_name)


def relative_target(r, path: tuple, target, ctx):
    """The multipliers that keep ``target`` in its range about the scene's value."""
    from .factors import Target

    name = target.name
    if target.category == "aps":
        base = getattr(ctx.binding.aps, name.removeprefix("aps."))
    else:
        base = ctx.base_value(name, ctx.binding.n)
    if not base > 0:
        raise r.error((*path, "relative"), f"the scene's {name} is {base:g}: scale a value > 0")
    return Target(
        name,
        "relative",
        low=target.low / base,
        high=target.high / base,
        low_open=target.low_open,
        high_open=target.high_open,
        long_name=f"multiplier of the scene's {name} = {base:g} {target.unit}",
    )


def _distribution(r, dist: str, raw, path: tuple, unit: str, check) -> tuple:
    if dist == "uniform":
        if not (isinstance(raw, list) and len(raw) == 2):
            raise r.error(path, f"{raw!r}: expected [low, high]")
        low, high = (r.quantity(v, path, unit) for v in raw)
        if not low < high:
            raise r.error(path, f"{raw!r}: need low < high")
        for v in (low, high):
            if not check.contains(v):
                raise r.error(path, check.refusal(v))
        return (low, high)
    keys = ("mean", "std") if dist == "normal" else ("median", "sigma")
    r.table(raw, path, keys, keys)
    center = r.quantity(raw[keys[0]], (*path, keys[0]), unit)
    spread = r.quantity(raw[keys[1]], (*path, keys[1]), unit if dist == "normal" else "1")
    if not spread > 0:
        raise r.error((*path, keys[1]), f"{raw[keys[1]]!r}: must be > 0")
    if dist == "lognormal" and not center > 0:
        raise r.error((*path, keys[0]), f"{raw[keys[0]]!r}: a lognormal median must be > 0")
    if not check.contains(center):
        raise r.error((*path, keys[0]), check.refusal(center))
    return (center, spread)


# ---------------------------------------------------------------------------- across


def check_factors(r, factors, ctx, kind: str) -> None:
    """Refuse two factors that set the same model parameter or input (one would silently
    do nothing), and an absolute APS factor the family member also sets (which wins?)."""
    from .designs import family_member

    where = section(kind)
    owner: dict[str, str] = {}
    for f in factors:
        for name in ctx.sets(f.name):
            if name in owner:
                raise r.error(
                    ("study", where, f.name),
                    f"'{f.name}' and '{owner[name]}' both set {name}; keep one",
                )
            owner[name] = f.name
    if "family" not in {f.name for f in factors}:
        return
    fields = family_member(FAMILY_DEFAULT_L_R)
    for f in factors:
        if f.name.startswith("aps.") and f.name[4:] in fields and not f.relative:
            raise r.error(
                ("study", where, f.name),
                f"the family member sets {f.name}; scale it with relative = true or remove "
                f"family ({', '.join(fields)} come with each member)",
            )


def check_every_n(r, factors, signals, ctx, kind: str) -> None:
    """With ``n`` a factor: every model parameter factor and named signal exists at every
    n (``myofibril.aps3...`` does not at n = 2)."""
    n_factor = next((f for f in factors if f.name == "n"), None)
    params = [f.name for f in factors if ctx.target(f.name).category == "parameter"]
    if n_factor is None or not (params or signals):
        return
    where = section(kind)
    for n in n_factor.values:
        model = ctx.model_at(int(n))
        for name in params:
            if name not in model.param_names:
                raise r.error(("study", where, name), f"no parameter '{name}' at n = {n:g}")
        for name in signals:
            if name not in model.signal_names:
                raise r.error(("study", where, "n"), f"n = {n:g} has no signal '{name}'")
