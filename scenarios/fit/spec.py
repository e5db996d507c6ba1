"""The fit file (TOML; docs/fitting.md): parsed and checked, every bad entry refused with
the file, line, key, value and what is allowed, before anything is built or solved.

Checks that need a model (parameter and signal names, units, input ranges) are made by
:mod:`.build` as the experiments are bound, still before any solve.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from sarcomere.dynamics.errors import ScenarioError
from sarcomere.dynamics.files import read_text

from ..loader import Reader, key_lines
from ..spec import KeyPath, did_you_mean, line_of
from .reference import ReferenceSpec, check_references, parse_reference

METHODS = ("multiple-shooting", "single-shooting")
KINDS = ("time-series", "static")
SECTIONS = ("fit", "parameters", "noise", "experiments", "design")
DESIGN_KEYS = ("kinds", "levels", "loads", "duration", "sample", "outputs")
DESIGN_KINDS = ("step", "staircase")
FIT_KEYS = ("name", "description", "method", "starts", "seed", "interval", "step")
PARAM_KEYS = ("start", "bounds", "scale", "per_experiment")
NOISE_KEYS = ("sigma", "relative")
EXP_KEYS = (
    "name",
    "kind",
    "data",
    "inputs",
    "outputs",
    "validation",
    "initial",
    "model",
    "reference",
)
MAX_STARTS = 10_000
MAX_STEP = 64
"""The most samples a Radau IIA step of a time series may span (``[fit] step``)."""


class FitError(ScenarioError):
    """A fit file or its data is malformed (file, line, key, value, what is allowed)."""


@dataclass(frozen=True)
class ParameterSpec:
    """``[parameters."<name>"]``: raw start and bounds (units checked against the model),
    log or linear search, one value per experiment or shared."""

    name: str
    start: object
    bounds: tuple[object, object]
    scale: str | None
    per_experiment: bool
    path: KeyPath


@dataclass(frozen=True)
class NoiseSpec:
    """``[noise."<signal>"]``: ``sigma`` raw ("estimate" -> None) and the relative part."""

    signal: str
    sigma: object | None
    relative: float
    path: KeyPath


@dataclass(frozen=True)
class ExperimentSpec:
    """One ``[[experiments]]`` entry."""

    index: int
    name: str
    kind: str
    data: Path
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    validation: bool
    model: dict
    path: KeyPath
    reference: ReferenceSpec | None = None


@dataclass(frozen=True)
class DesignSpec:
    """``[design]``: candidate experiments to rank (SI): input kinds, pressure levels,
    hanging loads, duration and sampling interval, measured signals."""

    kinds: tuple[str, ...]
    levels: tuple[float, ...]
    loads: tuple[float, ...]
    duration: float
    sample: float
    outputs: tuple[str, ...]


@dataclass
class FitSpec:
    """A parsed fit file."""

    name: str
    description: str
    method: str
    starts: int
    seed: int
    interval: int
    step: int | None  # samples per Radau IIA step at most; None: chosen per record
    parameters: list[ParameterSpec]
    noise: dict[str, NoiseSpec]
    experiments: list[ExperimentSpec]
    file: str
    lines: dict[KeyPath, int] = field(repr=False)
    design: DesignSpec | None = None

    def error(self, path: KeyPath, message: str) -> FitError:
        """A FitError at ``path`` (with its line)."""
        return FitError(self.file, _shown(path), message, line_of(self.lines, path))

    @property
    def base_dir(self) -> Path:
        return Path(self.file).parent


def _shown(path: KeyPath) -> str:
    """``experiments[2].model.n`` for ``("experiments", 1, "model", "n")``; names with dots
    quoted as in the file."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part + 1}]"
        else:
            text = f'"{part}"' if "." in part else part
            out += f".{text}" if out else text
    return out


def _lines(text: str) -> dict[KeyPath, int]:
    """Key lines, with each ``[[experiments]]`` block's keys under its index."""
    lines = {p: n for p, n in key_lines(text).items() if p[:1] != ("experiments",)}
    starts = [
        i
        for i, ln in enumerate(text.splitlines())
        if re.match(r"^\s*\[\[\s*experiments\s*\]\]", ln)
    ]
    body = text.splitlines()
    for k, first in enumerate(starts):
        last = starts[k + 1] if k + 1 < len(starts) else len(body)
        block = "\n".join(body[first:last])
        lines[("experiments", k)] = first + 1
        for p, n in key_lines(block).items():
            if p[:1] == ("experiments",) and len(p) > 1:
                lines[("experiments", k, *p[1:])] = first + n
    return lines


class _Reader(Reader):
    def error(self, path: KeyPath, message: str, key: str | None = None) -> FitError:
        return FitError(self.file, key or _shown(path), message, line_of(self.lines, path))


def load_fit(path: str | Path) -> FitSpec:
    """Read and check a fit file (FitError on any bad entry)."""
    text = read_text(Path(path))
    return parse_fit(text, str(path))


def parse_fit(text: str, file: str = "<string>") -> FitSpec:
    """Parse fit TOML ``text``; ``file`` names it in errors and anchors the data paths."""
    lines = _lines(text)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"at line (\d+)", str(exc))
        raise FitError(
            file, "(toml syntax)", f"TOML syntax error: {exc}", int(m[1]) if m else None
        ) from None
    r = _Reader(file, lines, FitError)
    r.table(data, (), SECTIONS, required=("fit", "parameters", "experiments"))
    head = r.table(data["fit"], ("fit",), FIT_KEYS)
    stem = Path(file).stem if file != "<string>" else "fit"
    name = r.text(head, ("fit",), "name", stem)
    if not re.match(r"^[A-Za-z0-9_.-]+$", name):
        raise r.error(("fit", "name"), f"'{name}': use letters, digits, '_', '-' and '.' only")
    method = r.choice(head, ("fit",), "method", METHODS, "multiple-shooting")
    starts = r.integer(head, ("fit",), "starts", 1, 1)
    if starts > MAX_STARTS:
        raise r.error(("fit", "starts"), f"{starts}: at most {MAX_STARTS}")
    seed = r.integer(head, ("fit",), "seed", 0, 0)
    interval = r.integer(head, ("fit",), "interval", 1, 50)
    step = r.integer(head, ("fit",), "step", 1, None)
    if step is not None and step > MAX_STEP:
        raise r.error(("fit", "step"), f"{step}: at most {MAX_STEP} samples per step")
    params = _parameters(r, data["parameters"])
    noise = _noise(r, data.get("noise", {}))
    exps = _experiments(r, data["experiments"], Path(file).parent)
    design = _design(r, data["design"]) if "design" in data else None
    spec = FitSpec(
        name,
        r.text(head, ("fit",), "description", ""),
        method,
        starts,
        seed,
        interval,
        step,
        params,
        noise,
        exps,
        file,
        lines,
        design,
    )
    _cross_checks(spec)
    return spec


def _parameters(r: _Reader, value: object) -> list[ParameterSpec]:
    tbl = r.table(value, ("parameters",))
    if not tbl:
        raise r.error(("parameters",), 'no parameter to estimate: add [parameters."<name>"]')
    out = []
    for name, entry in tbl.items():
        path = ("parameters", name)
        e = r.table(entry, path, PARAM_KEYS, required=("start", "bounds"))
        b = e["bounds"]
        if not (isinstance(b, list) and len(b) == 2):
            raise r.error((*path, "bounds"), f"{b!r}: expected [low, high] with units")
        scale = e.get("scale")
        if scale is not None and scale not in ("log", "linear"):
            raise r.error((*path, "scale"), f"'{scale}' is not one of log, linear")
        per = e.get("per_experiment", False)
        if not isinstance(per, bool):
            raise r.error((*path, "per_experiment"), f"{per!r}: expected true or false")
        out.append(ParameterSpec(name, e["start"], (b[0], b[1]), scale, per, path))
    return out


def _noise(r: _Reader, value: object) -> dict[str, NoiseSpec]:
    out = {}
    for signal, entry in r.table(value, ("noise",)).items():
        path = ("noise", signal)
        e = r.table(entry, path, NOISE_KEYS, required=("sigma",))
        sigma = None if e["sigma"] == "estimate" else e["sigma"]
        rel = r.number(e.get("relative", 0.0), (*path, "relative"), 0.0)
        if rel >= 1:
            raise r.error((*path, "relative"), f"{rel!r} is outside [0, 1)")
        if sigma is None and rel:
            raise r.error(
                (*path, "relative"),
                f'{rel!r}: a relative part needs a known sigma (0 when sigma = "estimate")',
            )
        out[signal] = NoiseSpec(signal, sigma, rel, path)
    return out


def _experiments(r: _Reader, value: object, base: Path) -> list[ExperimentSpec]:
    if not isinstance(value, list) or not value:
        raise r.error(("experiments",), "expected one or more [[experiments]] tables")
    out, names = [], set()
    for i, entry in enumerate(value):
        path = ("experiments", i)
        e = r.table(entry, path, EXP_KEYS, required=("kind", "data", "outputs", "model"))
        name = r.text(e, path, "name", f"experiment-{i + 1}")
        if name in names:
            raise r.error((*path, "name"), f"'{name}' is used twice: experiment names are unique")
        names.add(name)
        kind = r.choice(e, path, "kind", KINDS)
        data = base / r.text(e, path, "data")
        if not data.is_file():
            raise r.error(
                (*path, "data"), f"'{e['data']}': no such file (relative to the fit file)"
            )
        inputs = r.strings(e.get("inputs", []), (*path, "inputs"))
        outputs = r.strings(e["outputs"], (*path, "outputs"))
        if not outputs:
            raise r.error((*path, "outputs"), "[]: name at least one measured signal")
        validation = e.get("validation", False)
        if not isinstance(validation, bool):
            raise r.error((*path, "validation"), f"{validation!r}: expected true or false")
        initial = e.get("initial", "equilibrium")
        if initial != "equilibrium":
            raise r.error(
                (*path, "initial"), f"{initial!r}: only 'equilibrium' (at the first input value)"
            )
        model = r.table(e["model"], (*path, "model"))
        ref = parse_reference(r, e["reference"], (*path, "reference")) if "reference" in e else None
        out.append(
            ExperimentSpec(i, name, kind, data, inputs, outputs, validation, model, path, ref)
        )
    return out


def _design(r: _Reader, value: object) -> DesignSpec:
    path = ("design",)
    tbl = r.table(value, path, DESIGN_KEYS, required=("levels",))
    kinds = r.strings(tbl.get("kinds", ["step"]), (*path, "kinds"))
    for k in kinds:
        if k not in DESIGN_KINDS:
            raise r.error((*path, "kinds"), f"'{k}' is not one of {', '.join(DESIGN_KINDS)}")

    def quantities(key: str, unit: str, default) -> tuple[float, ...]:
        raw = tbl.get(key, default)
        if not isinstance(raw, list) or not raw:
            raise r.error((*path, key), f"{raw!r}: expected a non-empty list of quantities")
        return tuple(r.quantity(x, (*path, key), unit) for x in raw)

    duration = r.quantity(tbl.get("duration", "1 s"), (*path, "duration"), "s")
    sample = r.quantity(tbl.get("sample", "5 ms"), (*path, "sample"), "s")
    if not 0 < sample < duration:
        raise r.error((*path, "sample"), f"{tbl.get('sample')!r}: in (0, duration)")
    if duration / sample > 20_000:
        raise r.error((*path, "sample"), "more than 20000 samples per candidate")
    outputs = r.strings(tbl.get("outputs", []), (*path, "outputs"))
    return DesignSpec(
        kinds,
        quantities("levels", "Pa", None),
        quantities("loads", "kg", ["0 g"]),
        duration,
        sample,
        outputs,
    )


def _cross_checks(spec: FitSpec) -> None:
    fitted = [e for e in spec.experiments if not e.validation]
    if not fitted:
        raise spec.error(
            ("experiments",), "every experiment has validation = true: none is left to fit"
        )
    for p in spec.parameters:
        if p.per_experiment and len(fitted) < 2:
            raise spec.error(
                (*p.path, "per_experiment"),
                "true with a single fitted experiment: one value per experiment is the shared "
                "value; set per_experiment = false",
            )
    check_references(spec)
    measured = {s for e in spec.experiments for s in e.outputs}
    for signal, nz in spec.noise.items():
        if signal not in measured:
            raise spec.error(
                nz.path,
                f"'{signal}' is not measured by any experiment"
                + did_you_mean(signal, sorted(measured)),
            )
    if spec.design is not None:
        for s in spec.design.outputs:
            if s not in spec.noise:
                raise spec.error(("design", "outputs"), f"'{s}' has no [noise.\"{s}\"]")
    for e in spec.experiments:
        for s in e.outputs:
            if s not in spec.noise:
                raise spec.error(
                    (*e.path, "outputs"),
                    f'\'{s}\' has no [noise."{s}"] (a sigma with unit, or "estimate")',
                )
