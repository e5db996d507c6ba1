"""Read and check a design study: ``[study]`` in a scene TOML, or a study TOML naming a
``base`` scene (a packaged scene's name or a path relative to the study file) with
optional ``[model]``, ``[simulation]``, ``[solver]``, ... tables overriding the base's.

Everything is checked here, before any sample runs: unknown keys and factor names (with
the nearest names), values with wrong units or outside the parameter's range, invalid
distribution arguments, Sobol' counts that are not powers of two and sample counts above
``max_samples``. Each problem is a one-line :class:`StudyError` naming the key, the value
and what is allowed. Schema: ``docs/studies.md``.

Factor names (read in :mod:`.factor_spec`): ``n`` and ``load`` (scene options),
``pressure`` (the scene's name of the input ``regulator.p_cmd``: the level of its step or
ramp), ``family`` (a member of the calibration family,
by its ``L_r``: :data:`~.designs.FAMILY`), ``aps.<field>`` (an
:class:`~sarcomere.dynamics.components.aps.APSParams` field, every unit) or a model
parameter path (``myofibril.tube1.C``). ``relative = true`` makes a factor a multiplier
of the base value (unit 1).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import SarcomereError, ScenarioError
from sarcomere.dynamics.files import path_kind, read_text

from ..keylines import key_lines, key_parts
from ..loader import Reader, scenario_from_dict
from ..spec import did_you_mean, line_of, unknown_key
from . import factor_spec, packaged_studies
from .factor_spec import Factor
from .metric_def import MetricDef

KINDS = ("grid", "sample", "sensitivity")
SAMPLE_METHODS = ("lhs", "sobol", "montecarlo")
SENSITIVITY_METHODS = ("sobol", "morris")
MAX_SAMPLES = 100_000
"""Default cap on a study's sample count (``[study] max_samples`` sets another)."""

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
class SeriesDef:
    """Time series kept per sample, interpolated to ``time`` [s]."""

    signals: tuple[str, ...]
    time: tuple[float, ...]


@dataclass(frozen=True)
class StudyDef:
    """A checked study. Plain data: it pickles (it travels to Dask workers); the scene is
    checked again from ``scene_data`` where it is needed (:meth:`scene`).

    ``method``: "grid", "lhs", "sobol", "montecarlo", "sobol-saltelli" or "morris";
    ``count``: the number of samples; ``options``: the design's settings as sorted
    (key, value) pairs: ``grid_shape``; ``count``; ``base_count``, ``calc_second_order``
    (Sobol') or ``levels`` (Morris) and ``metrics`` (the metrics to analyse).
    ``source_text``: the study file's text; ``scene_data``: the merged scene (the base's
    TOML tables with the study file's on top, as parsed).
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
    scene_data: dict = field(hash=False)
    scene_file: str
    file: str = "<string>"
    description: str = ""
    fidelity: str = ""  # the level every sample runs, and why (summary.json)

    def definition(self) -> dict:
        """Canonical, JSON-serialisable; equal iff the same study: the scene it runs (base
        and overrides merged), the factors, design, metrics and series. The name, the
        description, how the base is written and ``max_samples`` (a cap) are left out;
        included parameter files count by their content."""
        files = self.scene_data.get("parameters", {}).get("include", [])
        return {
            **({"parameter_files": {f: _digest(f) for f in files}} if files else {}),
            "scene": self.scene_data,
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
        return scenario_from_dict(self.scene_data, self.scene_file)

    @property
    def factor_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.factors)


def _digest(path: str) -> str:
    """SHA-256 (hex) of an included parameter file's bytes ("missing" if unreadable)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "missing"


def _check_draws(study: StudyDef, design) -> None:
    """Refuse a design whose unbounded draws (normal, lognormal) leave a factor's range,
    naming the factor, the first such value and the range."""
    from .factors import scene_context

    ctx = None
    for j, f in enumerate(study.factors):
        if f.dist not in ("normal", "lognormal"):
            continue
        r = Reader(study.file, key_lines(study.source_text), StudyError)
        path = ("study", "factors", f.name, f.dist)
        ctx = ctx or scene_context(study.scene())
        target = ctx.target(f.name)
        check = factor_spec.relative_target(r, path, target, ctx) if f.relative else target
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


def load_study(source: str | Path, parameters: str | Path | None = None) -> StudyDef:
    """Read and check a study given as a file path or a packaged study's name;
    ``parameters``: a parameter file included last (``--parameters FILE``).

    Raises
    ------
    StudyError
        Any problem of the study or its base scene, one line, before any work.
    """
    text, file = _resolve(source)
    return parse_study(text, file, parameters)


def _includes(data: dict, anchor: str) -> list:
    """``[parameters] include`` of scene data as a list, relative paths made absolute
    against ``anchor``'s folder (a wrong type is left for the scene's check)."""
    files = data.get("parameters", {}).get("include", []) if isinstance(data, dict) else []
    files = [files] if isinstance(files, str) else files
    if not isinstance(files, list):
        return files
    return [str(Path(anchor).parent / f) if isinstance(f, str) else f for f in files]


def parse_study(
    text: str, file: str = "<string>", parameters: str | Path | None = None
) -> StudyDef:
    """Parse and check study TOML ``text``; ``file`` names it in errors and anchors a
    relative ``base`` and ``[parameters] include``; ``parameters``: a parameter file
    included after the scene's (``--parameters FILE``)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(file, "(toml syntax)", f"TOML syntax error: {exc}") from None
    lines = key_lines(text)
    r = Reader(file, lines, StudyError)
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
        if "fidelity" in data.get("model", {}):  # the base's auto tolerance goes with it
            base_data.get("outputs", {}).pop("tolerance", None)
        base_lines = key_lines(base_text)
        includes = _includes(base_data, scene_file) + _includes(data, file)
        scene_data = _merge(base_data, data)
    elif "scenario" not in data:
        raise r.error(("study", "base"), "a study TOML without [scenario] needs base = SCENE")
    else:
        includes = _includes(data, file)
    includes += [str(Path(parameters).absolute())] if parameters is not None else []
    if includes:  # the base's, the study's, then --parameters: later ones override
        scene_data["parameters"] = {**scene_data.get("parameters", {}), "include": includes}
    sc, ctx = _parse_scene(scene_data, scene_file, file, lines, base_lines)
    name = r.text(study, ("study",), "name", Path(file).stem if file != "<string>" else sc.name)
    return _check_study(r, study, ctx, name, base or sc.name, text, scene_data, scene_file)


def _parse_scene(data: dict, scene_file: str, file: str, lines: dict, base_lines: dict):
    """The merged scene and its :class:`~.factors.SceneContext`; an error is placed in the
    study file if it wrote the key, else in the base scene (or its parameter file)."""
    from .factors import scene_context

    try:
        sc = scenario_from_dict(data, scene_file)
        return sc, scene_context(sc)
    except ScenarioError as exc:
        path = key_parts(exc.key)
        message = str(exc).split(f"key '{exc.key}': ", 1)[-1]
        if exc.file not in (file, scene_file):  # in an included parameter file
            raise StudyError(exc.file, exc.key, message, exc.line) from None
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


# ---------------------------------------------------------------------------- checking

_NEEDS = {
    "grid": (("grid",), ("sample", "factors", "sensitivity")),
    "sample": (("sample", "factors"), ("grid", "sensitivity")),
    "sensitivity": (("sensitivity", "factors"), ("grid", "sample")),
}


def signal_unit(study: StudyDef, signal: str) -> str:
    """The SI unit of a model signal of the study's scene (its model bound once per
    process), ``"?"`` when it cannot be told."""
    from .factors import scene_context

    try:
        return str(scene_context(study.scene()).model.unit(signal))
    except (SarcomereError, KeyError, AttributeError):
        return "?"


def _check_study(r: Reader, study, ctx, name, base, text, scene_data, scene_file) -> StudyDef:
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
        factors, method, options = factor_spec.read_grid(r, study["grid"], ctx), "grid", {}
        options["grid_shape"] = [len(f.values) for f in factors]
        size_key = (*S, "grid")
    else:
        factors = factor_spec.read_factors(r, study["factors"], ctx, kind)
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
    factor_spec.check_factors(r, factors, ctx, kind)
    signals = [m.signal for m in metrics if m.signal] + list(series.signals if series else ())
    factor_spec.check_every_n(r, factors, signals, ctx, kind)
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
        scene_data=scene_data,
        scene_file=scene_file,
        file=r.file,
        description=r.text(study, ("study",), "description", ""),
        fidelity=ctx.level_note,
    )


def _power_of_two(r: Reader, path: tuple, value: int, what: str) -> None:
    if value & (value - 1):
        low = 1 << (value.bit_length() - 1)
        raise r.error(
            path, f"{value} is not a power of two ({what} needs one): use {low} or {2 * low}"
        )


def _sample(r: Reader, tbl) -> tuple[str, dict]:
    path = ("study", "sample")
    r.table(tbl, path, ("method", "count"), ("method", "count"))
    method = r.choice(tbl, path, "method", SAMPLE_METHODS)
    count = r.integer(tbl, path, "count", 1)
    if method == "sobol":
        _power_of_two(r, (*path, "count"), count, "a scrambled Sobol' sequence")
    return method, {"count": count}


def _sensitivity(r: Reader, tbl, factors) -> tuple[str, dict]:
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


def _metrics(r: Reader, study, ctx, kind, options):
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


def _series(r: Reader, study, ctx) -> SeriesDef | None:
    if "series" not in study:
        return None
    path = ("study", "series")
    tbl = r.table(study["series"], path, ("signals", "grid"), ("signals", "grid"))
    signals = tbl["signals"]
    if not (isinstance(signals, list) and signals and all(isinstance(s, str) for s in signals)):
        raise r.error((*path, "signals"), f"{signals!r}: expected a list of signal names")
    for i, s in enumerate(signals):
        if s in signals[:i]:
            raise r.error((*path, "signals"), f"'{s}' is given twice")
        if s not in ctx.model.signal_names:
            hint = did_you_mean(s, ctx.model.signal_names)
            raise r.error((*path, "signals"), f"'{s}' is not a signal of the model{hint}")
    from .factors import Target

    sim = ctx.scene.simulation
    span = Target("time", "time", unit="s", low=sim.start_time, high=sim.stop_time)
    times = factor_spec.read_values(r, tbl["grid"], (*path, "grid"), span)
    return SeriesDef(tuple(signals), times)
