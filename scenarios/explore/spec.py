"""Read and check a design study: ``[study]`` in a scene TOML, or a study TOML naming a
``base`` scene (a packaged scene's name or a path relative to the study file) with
optional ``[model]``, ``[simulation]``, ``[solver]``, ... tables overriding the base's.

Everything is checked here, before any sample runs: unknown keys and factor names (with
the nearest names), values with wrong units or outside the parameter's range, invalid
distribution arguments, Sobol' counts that are not powers of two and sample counts above
``max_samples``. Each problem is a one-line :class:`StudyError` naming the key, the value
and what is allowed. Schema: ``docs/studies.md``.

Factor names: ``n`` and ``load`` (scene options), ``pressure`` (the level of the scene's
step or ramp on the regulator command), ``family`` (a member of the calibration family,
by its ``L_r``: :data:`~.designs.FAMILY`), ``aps.<field>`` (an
:class:`~sarcomere.dynamics.components.aps.APSParams` field, every unit) or a model
parameter path (``myofibril.tube1.C``). ``relative = true`` makes a factor a multiplier
of the base value (unit 1).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError, SarcomereError, ScenarioError
from sarcomere.dynamics.files import path_kind, read_text

from .. import loader
from ..spec import describe, did_you_mean, dotted, line_of, unknown_key
from . import packaged_studies
from .metric_def import MetricDef

KINDS = ("grid", "sample", "sensitivity")
SAMPLE_METHODS = ("lhs", "sobol", "montecarlo")
SENSITIVITY_METHODS = ("sobol", "morris")
DISTRIBUTIONS = ("uniform", "normal", "lognormal", "levels")
MAX_SAMPLES = 100_000
"""Default cap on a study's sample count (``[study] max_samples`` sets another)."""

OPTION_FACTORS = ("n", "load", "pressure", "family")
_STUDY_KEYS = (
    "name",
    "base",
    "kind",
    "seed",
    "batch",
    "max_samples",
    "grid",
    "sample",
    "factors",
    "sensitivity",
    "metrics",
    "series",
    "description",
)


class StudyError(ScenarioError):
    """A study definition is malformed: names the file, the key (and line), the value and
    what is allowed."""


@dataclass(frozen=True)
class Factor:
    """One input of a study, values in SI.

    Parameters
    ----------
    name : str
        ``n``, ``load``, ``pressure``, ``family``, ``aps.<field>`` or a model parameter.
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


@dataclass(frozen=True)
class SeriesDef:
    """Time series kept per sample, interpolated to ``time`` [s]."""

    signals: tuple[str, ...]
    time: tuple[float, ...]


@dataclass(frozen=True)
class StudyDef:
    """A checked study. Plain data: it pickles (it travels to Dask workers); the scene is
    parsed again from ``scene_text`` where it is needed (:meth:`scene`).

    ``method``: "grid", "lhs", "sobol", "montecarlo", "sobol-saltelli" or "morris";
    ``count``: the number of samples; ``options``: the design's settings as sorted
    (key, value) pairs: ``grid_shape``; ``count``; ``base_count``, ``calc_second_order``
    (Sobol') or ``levels`` (Morris) and ``metrics`` (the metrics to analyse).
    ``source_text``: the study file's text; ``scene_text``: the merged scene (TOML).
    """

    name: str
    base: str
    kind: str
    method: str
    factors: tuple[Factor, ...]
    metrics: tuple[MetricDef, ...]
    series: SeriesDef | None
    seed: int | None
    batch: int | None
    max_samples: int
    count: int
    options: tuple[tuple[str, object], ...]
    source_text: str
    scene_text: str
    scene_file: str
    file: str = "<string>"
    description: str = ""

    def definition(self) -> dict:
        """Canonical, JSON-serialisable; equal iff the same study: the scene it runs (base
        and overrides merged), the factors, design, metrics and series. The name, the
        description, how the base is written and ``max_samples`` (a cap) are left out."""
        return {
            "scene": tomllib.loads(self.scene_text),
            "kind": self.kind,
            "method": self.method,
            "factors": [f.definition() for f in self.factors],
            "metrics": [dataclasses.asdict(m) for m in self.metrics],
            "series": None if self.series is None else dataclasses.asdict(self.series),
            "seed": self.seed,
            "batch": self.batch,
            "count": self.count,
            "options": dict(self.options),
        }

    def fingerprint(self) -> str:
        """SHA-256 (hex) of the canonical definition."""
        text = json.dumps(self.definition(), sort_keys=True, allow_nan=False)
        return hashlib.sha256(text.encode()).hexdigest()

    def design(self):
        """The sample points (:class:`~.designs.Design`); a StudyError if a point drawn
        from a normal or lognormal lies outside its parameter's range."""
        from .designs import make_design

        design = make_design(self)
        _check_draws(self, design)
        return design

    def scene(self):
        """The base scene with this study's overrides (a
        :class:`~sarcomere.scenarios.spec.Scenario`)."""
        from ..loader import parse_scenario

        return parse_scenario(self.scene_text, self.scene_file)

    @property
    def factor_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.factors)


def _check_draws(study: StudyDef, design) -> None:
    """Refuse a design whose unbounded draws (normal, lognormal) leave a factor's range,
    naming the factor, the first such value and the range."""
    from ..loader import key_lines

    ctx = None
    for j, f in enumerate(study.factors):
        if f.dist not in ("normal", "lognormal"):
            continue
        r = _Reader(study.file, key_lines(study.source_text))
        path = ("study", "factors", f.name, f.dist)
        ctx = ctx or scene_context(study.scene())
        target = ctx.target(f.name)
        check = _relative_target(r, path, target, ctx) if f.relative else target
        bad = [v for v in design.points[:, j] if not check.contains(v)]
        if bad:
            i = int(np.flatnonzero(design.points[:, j] == bad[0])[0])
            raise r.error(
                path,
                f"sample {i} draws {check.refusal(bad[0])} ({len(bad)} of {len(design.points)} "
                "draws outside); narrow the distribution or use uniform",
            )


# ---------------------------------------------------------------------------- loading


def _resolve(source: str | Path, anchor: Path | None = None) -> tuple[str, str]:
    """(text, path label) of a study or scene: a file path (relative to ``anchor``'s
    folder if given: a base scene), a packaged study (not for a base) or a packaged scene
    by name."""
    from ..catalog import packaged_scenarios

    text = str(source)
    path = Path(source) if anchor is None or Path(source).is_absolute() else anchor.parent / source
    bare = not ("/" in text or "\\" in text or text.endswith(".toml"))
    tables = (packaged_scenarios(),) if anchor else (packaged_studies(), packaged_scenarios())
    if bare:
        for table in tables:
            if text in table:
                with resources.as_file(table[text]) as p:
                    return read_text(p), str(p)
    kind = path_kind(path)
    if kind is None:
        try:
            return read_text(path), str(path)
        except ValueError as exc:
            raise StudyError(str(path), "study", str(exc)) from None
    names = [name for table in tables for name in table]
    hint = did_you_mean(text, names) if bare else ""
    packaged = "packaged scene" if anchor else "packaged study or scene"
    what = f"no such file or {packaged}" if bare else f"{kind}"
    if anchor is None:
        raise StudyError(text, "study", f"{what}{hint}")
    raise StudyError(str(anchor), "study.base", f"'{text}': {what}{hint}")


def load_study(source: str | Path) -> StudyDef:
    """Read and check a study given as a file path or a packaged study's name.

    Raises
    ------
    StudyError
        Any problem of the study or its base scene, one line, before any work.
    """
    text, file = _resolve(source)
    return parse_study(text, file)


def parse_study(text: str, file: str = "<string>") -> StudyDef:
    """Parse and check study TOML ``text``; ``file`` names it in errors and anchors a
    relative ``base``."""
    from ..loader import key_lines

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(file, "(toml syntax)", f"TOML syntax error: {exc}") from None
    lines = key_lines(text)
    r = _Reader(file, lines)
    if "study" not in data:
        raise r.error(("study",), "missing the [study] table (see docs/studies.md)")
    study = r.table(data.pop("study"), ("study",), _STUDY_KEYS, ("kind",))
    scene_data, scene_file, base, base_lines = data, file, "", lines
    if "base" in study:
        base = r.text(study, ("study",), "base")
        base_text, scene_file = _resolve(base, Path(file))
        try:
            base_data = tomllib.loads(base_text)
        except tomllib.TOMLDecodeError as exc:
            raise StudyError(scene_file, "(toml syntax)", f"TOML syntax error: {exc}") from None
        base_data.pop("study", None)  # the base's own study is not this one
        base_lines = key_lines(base_text)
        scene_data = _merge(base_data, data)
    elif "scenario" not in data:
        raise r.error(("study", "base"), "a study TOML without [scenario] needs base = SCENE")
    scene_text = dump_toml(scene_data)
    sc, ctx = _parse_scene(scene_text, scene_file, file, lines, base_lines)
    name = r.text(study, ("study",), "name", Path(file).stem if file != "<string>" else sc.name)
    return _check_study(r, study, ctx, name, base or sc.name, text, scene_text, scene_file)


def _parse_scene(text: str, scene_file: str, file: str, lines: dict, base_lines: dict):
    """The merged scene and its :class:`~.factors.SceneContext`; an error is placed in the
    study file if it wrote the key, else in the base scene."""
    from ..loader import _key_parts, parse_scenario

    try:
        sc = parse_scenario(text, scene_file)
        return sc, scene_context(sc)
    except ScenarioError as exc:
        path = _key_parts(exc.key)
        message = str(exc).split(f"key '{exc.key}': ", 1)[-1]
        if line_of(lines, path) and file != scene_file:
            raise StudyError(file, exc.key, message, line_of(lines, path)) from None
        raise StudyError(scene_file, exc.key, message, line_of(base_lines, path)) from None


def _merge(base: dict, over: dict) -> dict:
    """``over`` on ``base``: tables merged key by key, anything else replaced."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def dump_toml(data: dict) -> str:
    """TOML text of ``data`` (tables, arrays, strings, numbers, booleans), for the loader.

    >>> dump_toml({"a": {"b.c": [1, "x"], "d": {"e": 1.5}}})
    '[a]\\n"b.c" = [1, "x"]\\n\\n[a.d]\\ne = 1.5\\n'
    """
    out: list[str] = []
    _dump_table(data, (), out)
    return "\n".join(out).lstrip("\n") + "\n"


def _dump_table(tbl: dict, path: tuple, out: list[str]) -> None:
    scalars = {k: v for k, v in tbl.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in tbl.items() if isinstance(v, dict)}
    if path and (scalars or not tables):
        out.append(f"\n[{dotted(path)}]" if out else f"[{dotted(path)}]")
    out.extend(f"{dotted((k,))} = {_value(v)}" for k, v in scalars.items())
    for k, v in tables.items():
        _dump_table(v, (*path, k), out)


def _value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{dotted((k,))} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {v!r} as TOML")


# ---------------------------------------------------------------------------- reading


class _Reader(loader._Reader):
    """Typed access to ``[study]``, turning every problem into a StudyError."""

    error_class = StudyError

    def integer(self, tbl: dict, path: tuple, key: str, low: int, default=None) -> int | None:
        value = tbl.get(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.error((*path, key), f"{value!r}: expected an integer >= {low}")
        return value


# ---------------------------------------------------------------------------- checking

_NEEDS = {
    "grid": (("grid",), ("sample", "factors", "sensitivity")),
    "sample": (("sample", "factors"), ("grid", "sensitivity")),
    "sensitivity": (("sensitivity", "factors"), ("grid", "sample")),
}


def scene_context(sc):
    """The :class:`~.factors.SceneContext` of a scene, bound once per process and scene
    text (it builds the base model)."""
    from .factors import SceneContext

    key = (sc.file, repr(sc))
    if key not in _CONTEXTS:
        _CONTEXTS[key] = SceneContext(sc)
    return _CONTEXTS[key]


_CONTEXTS: dict = {}


def signal_unit(study: StudyDef, signal: str) -> str:
    """The SI unit of a model signal of the study's scene (its model bound once per
    process), ``"?"`` when it cannot be told."""
    try:
        return str(scene_context(study.scene()).model.unit(signal))
    except (SarcomereError, KeyError, AttributeError):
        return "?"


def _check_study(r: _Reader, study, ctx, name, base, text, scene_text, scene_file) -> StudyDef:
    S = ("study",)
    kind = r.choice(study, S, "kind", KINDS)
    seed = r.integer(study, S, "seed", 0)
    if kind != "grid" and seed is None:
        raise r.error((*S, "seed"), f"missing: kind '{kind}' draws points; give an integer >= 0")
    if kind == "grid" and seed is not None:
        raise r.error((*S, "seed"), f"{seed!r}: a grid draws nothing at random; remove it")
    batch = r.integer(study, S, "batch", 1)
    max_samples = r.integer(study, S, "max_samples", 1, MAX_SAMPLES)
    needed, refused = _NEEDS[kind]
    for key in needed:
        if key not in study:
            raise r.error((*S, key), f"missing: kind '{kind}' needs [study.{key}]")
    for key in refused:
        if key in study:
            raise r.error((*S, key), f"kind '{kind}' does not use [study.{key}]; remove it")
    if kind == "grid":
        factors, method, options = _grid(r, study["grid"], ctx), "grid", {}
        options["grid_shape"] = [len(f.values) for f in factors]
        size_key = (*S, "grid")
    else:
        factors = _factors(r, study["factors"], ctx, kind)
        if kind == "sample":
            method, options = _sample(r, study["sample"])
            size_key = (*S, "sample", "count")
        else:
            method, options = _sensitivity(r, study["sensitivity"], factors)
            size_key = (*S, "sensitivity", "base_count")
    from .designs import sample_count

    count = sample_count(kind, method, len(factors), options)
    if count > max_samples:
        raise r.error(
            size_key,
            f"the study has {count} samples, above max_samples = {max_samples}; use fewer "
            "points or raise [study] max_samples",
        )
    metrics, series = _metrics(r, study, ctx, kind, options)
    _check_every_n(r, factors, metrics, series, ctx, kind)
    _check_family(r, factors, kind)
    return StudyDef(
        name=name,
        base=base,
        kind=kind,
        method=method,
        factors=factors,
        metrics=metrics,
        series=series,
        seed=seed,
        batch=batch,
        max_samples=max_samples,
        count=count,
        options=tuple(
            sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in options.items())
        ),
        source_text=text,
        scene_text=scene_text,
        scene_file=scene_file,
        file=r.file,
        description=r.text(study, ("study",), "description", ""),
    )


def _check_family(r: _Reader, factors, kind: str) -> None:
    """Refuse an absolute APS factor the family member also sets (which would win?)."""
    from .designs import family_member

    if "family" not in {f.name for f in factors}:
        return
    fields = family_member(FAMILY_DEFAULT_L_R)
    for f in factors:
        if f.name.startswith("aps.") and f.name[4:] in fields and not f.relative:
            raise r.error(
                ("study", "grid" if kind == "grid" else "factors", f.name),
                f"the family member sets {f.name}; scale it with relative = true or remove "
                f"family ({', '.join(fields)} come with each member)",
            )


#: Any member's L_r (only its field names are used).
FAMILY_DEFAULT_L_R = 20e-3


def _check_every_n(r: _Reader, factors, metrics, series, ctx, kind: str) -> None:
    """With ``n`` a factor: every model parameter factor and named signal exists at every
    n (``myofibril.aps3...`` does not at n = 2)."""
    n_factor = next((f for f in factors if f.name == "n"), None)
    params = [f.name for f in factors if f.name not in OPTION_FACTORS and "." in f.name]
    params = [p for p in params if not p.startswith("aps.")]
    signals = [m.signal for m in metrics if m.signal] + list(series.signals if series else ())
    if n_factor is None or not (params or signals):
        return
    section = "grid" if kind == "grid" else "factors"
    for n in n_factor.values:
        model = ctx.model_at(int(n))
        for name in params:
            if name not in model.param_names:
                raise r.error(("study", section, name), f"no parameter '{name}' at n = {n:g}")
        for name in signals:
            if name not in model.signal_names:
                raise r.error(("study", section, "n"), f"n = {n:g} has no signal '{name}'")


def _target(r: _Reader, path: tuple, name: str, ctx):
    try:
        return ctx.target(name)
    except ParameterError as exc:
        raise r.error(path, describe(exc)) from None


def _values(r: _Reader, raw, path: tuple, target) -> tuple[float, ...]:
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


def _grid(r: _Reader, tbl, ctx) -> tuple[Factor, ...]:
    path = ("study", "grid")
    r.table(tbl, path)
    if not tbl:
        raise r.error(path, "give at least one axis")
    out = []
    for name, raw in tbl.items():
        target = _target(r, (*path, name), name, ctx)
        _check_aps(r, (*path, name), target, ctx, discrete=True)
        values = _values(r, raw, (*path, name), target)
        out.append(Factor(name, target.unit, "discrete", values, long_name=target.long_name))
    return tuple(out)


def _check_aps(r: _Reader, path: tuple, target, ctx, discrete: bool) -> None:
    """Refuse an APS field that sets no parameter of the model (it would change nothing),
    or one that is not a run-time parameter (one model per value) drawn continuously."""
    if target.category != "aps":
        return
    from .factors import aps_map

    b, field = ctx.binding, target.name.removeprefix("aps.")
    mapped = aps_map(b, ctx.key, ctx.fidelity, b.n, field)
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


def _factors(r: _Reader, tbl, ctx, kind: str) -> tuple[Factor, ...]:
    path = ("study", "factors")
    r.table(tbl, path)
    if not tbl:
        raise r.error(path, "give at least one factor")
    return tuple(_factor(r, name, item, (*path, name), ctx, kind) for name, item in tbl.items())


def _factor(r: _Reader, name: str, item, path: tuple, ctx, kind: str) -> Factor:
    target = _target(r, path, name, ctx)
    r.table(item, path, (*DISTRIBUTIONS, "relative"))
    given = [d for d in DISTRIBUTIONS if d in item]
    if len(given) != 1:
        raise r.error(
            path, f"give exactly one of {', '.join(DISTRIBUTIONS)} (got {given or 'none'})"
        )
    dist = given[0]
    _check_aps(r, path, target, ctx, dist == "levels")
    relative = item.get("relative", False)
    if not isinstance(relative, bool):
        raise r.error((*path, "relative"), f"{relative!r}: expected true or false")
    if relative and target.category not in ("aps", "parameter"):
        raise r.error((*path, "relative"), f"'{name}' has no base value to scale; remove it")
    if target.category in ("n", "family") and dist != "levels":
        raise r.error((*path, dist), f"'{name}' takes discrete values: use levels = [...]")
    if kind == "sensitivity" and dist == "levels":
        raise r.error((*path, dist), "a sensitivity study needs continuous factors")
    unit = "1" if relative else target.unit

    check = _relative_target(r, path, target, ctx) if relative else target
    where = (*path, dist)
    if dist == "levels":
        values = _values(r, item[dist], where, check)
        return Factor(name, unit, "discrete", values, relative=relative, long_name=target.long_name)
    args = _distribution(r, dist, item[dist], where, unit, check)
    long_name = f"{target.long_name} (relative)" if relative else target.long_name
    return Factor(name, unit, "continuous", (), dist, args, relative, long_name)


def _relative_target(r: _Reader, path: tuple, target, ctx):
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


def _distribution(r: _Reader, dist: str, raw, path: tuple, unit: str, check) -> tuple:
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


def _power_of_two(r: _Reader, path: tuple, value: int, what: str) -> None:
    if value & (value - 1):
        low = 1 << (value.bit_length() - 1)
        raise r.error(
            path, f"{value} is not a power of two ({what} needs one): use {low} or {2 * low}"
        )


def _sample(r: _Reader, tbl) -> tuple[str, dict]:
    path = ("study", "sample")
    r.table(tbl, path, ("method", "count"), ("method", "count"))
    method = r.choice(tbl, path, "method", SAMPLE_METHODS)
    count = r.integer(tbl, path, "count", 1)
    if method == "sobol":
        _power_of_two(r, (*path, "count"), count, "a scrambled Sobol' sequence")
    return method, {"count": count}


def _sensitivity(r: _Reader, tbl, factors) -> tuple[str, dict]:
    path = ("study", "sensitivity")
    keys = ("method", "base_count", "levels", "second_order", "metrics")
    r.table(tbl, path, keys, ("method", "base_count", "metrics"))
    method = r.choice(tbl, path, "method", SENSITIVITY_METHODS)
    base_count = r.integer(tbl, path, "base_count", 2 if method == "morris" else 1)
    names = tbl["metrics"]
    if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
        raise r.error((*path, "metrics"), f"{names!r}: expected a list of metric names")
    if method == "sobol":
        if "levels" in tbl:
            raise r.error((*path, "levels"), "Morris only; remove it")
        _power_of_two(r, (*path, "base_count"), base_count, "SALib's Sobol' (Saltelli) design")
        second = tbl.get("second_order", False)
        if not isinstance(second, bool):
            raise r.error((*path, "second_order"), f"{second!r}: expected true or false")
        options = {"base_count": base_count, "calc_second_order": second}
        return "sobol-saltelli", {**options, "metrics": tuple(names)}
    if "second_order" in tbl:
        raise r.error((*path, "second_order"), "Sobol' only; remove it")
    levels = r.integer(tbl, path, "levels", 2, 4)
    if levels % 2:
        raise r.error((*path, "levels"), f"{levels}: Morris needs an even number of levels")
    return "morris", {"base_count": base_count, "levels": levels, "metrics": tuple(names)}


def _metrics(r: _Reader, study, ctx, kind, options):
    from .metrics import STANDARD, chambers, metric_signals, value_at_metric

    path = ("study", "metrics")
    tbl = r.table(study.get("metrics", {}), path, ("names", "value_at"))
    every_chamber = len(chambers(ctx.model.signal_names)) == ctx.binding.n
    default = [n for n in STANDARD if every_chamber or n != "air_mass"]
    names = tbl.get("names", default)
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise r.error((*path, "names"), f"{names!r}: expected a list of metric names")
    out = {}
    for n in names:
        if n not in STANDARD:
            raise r.error((*path, "names"), unknown_key(n, list(STANDARD)).replace("key", "metric"))
        out[n] = MetricDef(n, *STANDARD[n])
    if "air_mass" in out and not every_chamber:
        raise r.error(
            (*path, "names"),
            f"'air_mass' sums every unit's chamber; fidelity '{ctx.fidelity}' does not name "
            "each (use 'full')",
        )
    for n in out:
        if not metric_signals(n, ctx.model.signal_names):
            raise r.error((*path, "names"), f"'{n}': the model has no signal it reads")
    sim = ctx.scene.simulation
    for label, spec in r.table(tbl.get("value_at", {}), (*path, "value_at")).items():
        where = (*path, "value_at", label)
        r.table(spec, where, ("signal", "time"), ("signal", "time"))
        signal = r.text(spec, where, "signal")
        if signal not in ctx.model.signal_names:
            hint = did_you_mean(signal, ctx.model.signal_names)
            raise r.error((*where, "signal"), f"'{signal}' is not a signal of the model{hint}")
        t = r.quantity(spec["time"], (*where, "time"), "s")
        if not sim.start_time <= t <= sim.stop_time:
            span = f"[{sim.start_time:g}, {sim.stop_time:g}] s"
            raise r.error((*where, "time"), f"{t:g} s is outside the simulation {span}")
        if label in out:
            raise r.error(where, f"'{label}' is already a metric's name")
        out[label] = value_at_metric(label, signal, t, ctx.model.unit(signal))
    for n in options.get("metrics", ()):
        if n not in out:
            known = list(STANDARD) + list(out)
            if n not in STANDARD:
                hint = did_you_mean(n, known)
                raise r.error(("study", "sensitivity", "metrics"), f"unknown metric '{n}'{hint}")
            out[n] = MetricDef(n, *STANDARD[n])
    if not out:
        raise r.error((*path, "names"), "no metrics: name at least one")
    return tuple(out.values()), _series(r, study, ctx)


def _series(r: _Reader, study, ctx) -> SeriesDef | None:
    if "series" not in study:
        return None
    path = ("study", "series")
    tbl = r.table(study["series"], path, ("signals", "grid"), ("signals", "grid"))
    signals = tbl["signals"]
    if not (isinstance(signals, list) and signals and all(isinstance(s, str) for s in signals)):
        raise r.error((*path, "signals"), f"{signals!r}: expected a list of signal names")
    for s in signals:
        if s not in ctx.model.signal_names:
            hint = did_you_mean(s, ctx.model.signal_names)
            raise r.error((*path, "signals"), f"'{s}' is not a signal of the model{hint}")
    from .factors import Target

    sim = ctx.scene.simulation
    span = Target("time", "time", unit="s", low=sim.start_time, high=sim.stop_time)
    times = _values(r, tbl["grid"], (*path, "grid"), span)
    return SeriesDef(tuple(signals), times)
