"""Static outputs measured against a reference equilibrium: a fit file's
``[experiments.reference]`` (docs/fitting.md, "Relative and tared outputs").

A lab often records a static curve against the actuator's own state at a reference
input: the contraction ``L / L_0`` against the length at 0 Pa, or a force tared at 0 Pa
(the load cell zeroed there, ``F - F_0``). ``form = "ratio"`` compares each measured
value with ``y / y_ref`` (its data column dimensionless: ``[1]`` or ``[%]``);
``form = "difference"`` with ``y - y_ref`` (its column in a unit of the signal). ``y_ref``
is the same signal at the equilibrium of the reference set-up (this experiment's, or
``experiment = "<name>"``'s: the calibration's loaded ratio is against the unloaded chain)
at the reference ``inputs``. That equilibrium is one more static point of the fit (its
equations constraints, so the reference follows the estimated parameters), shared by every
experiment that names the same set-up and inputs; the comparison is a
:class:`~sarcomere.dynamics.identification.experiments.Target` expression on the two
points' solved signals, as the calibration's targets are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.identification.experiments import Target
from sarcomere.dynamics.modeling.model import Model
from sarcomere.dynamics.units import to_si

from ..binding import INPUT_ALIASES, command_range
from ..spec import KeyPath, did_you_mean

FORMS = ("ratio", "difference")
KEYS = ("form", "inputs", "experiment")


@dataclass(frozen=True)
class ReferenceSpec:
    """``[experiments.reference]``: the form, the reference's input values (raw, as
    written, by input name or alias) and the experiment whose set-up it is (None: the
    experiment's own)."""

    form: str
    inputs: dict
    experiment: str | None
    path: KeyPath


def parse_reference(r, value: object, path: KeyPath) -> ReferenceSpec:
    """Read ``[experiments.reference]`` with the fit file's reader ``r``."""
    tbl = r.table(value, path, KEYS, required=("form", "inputs"))
    form = r.choice(tbl, path, "form", FORMS)
    inputs = r.table(tbl["inputs"], (*path, "inputs"))
    if not inputs:
        raise r.error(
            (*path, "inputs"), '{}: give the reference\'s inputs, e.g. { pressure = "0 MPa" }'
        )
    experiment = tbl.get("experiment")
    if experiment is not None and not isinstance(experiment, str):
        raise r.error((*path, "experiment"), f"expected an experiment's name, got {experiment!r}")
    return ReferenceSpec(form, dict(inputs), experiment, path)


def is_ratio(exp) -> bool:
    """Whether experiment ``exp`` (an ExperimentSpec) measures its outputs as ratios."""
    return exp.reference is not None and exp.reference.form == "ratio"


def check_references(spec) -> None:
    """Cross-checks of a parsed fit file: a reference belongs to a static experiment and
    names an experiment of the file; a signal is measured either as a ratio everywhere or
    in its unit everywhere (one noise level per signal, in one unit)."""
    names = [e.name for e in spec.experiments]
    form_of: dict[str, tuple[bool, str]] = {}
    for e in spec.experiments:
        ref = e.reference
        if ref is not None and e.kind != "static":
            raise spec.error(
                ref.path,
                f"a reference is for static experiments; '{e.name}' is a {e.kind} "
                "(measure its outputs in their units)",
            )
        if ref is not None and ref.experiment is not None and ref.experiment not in names:
            raise spec.error(
                (*ref.path, "experiment"),
                f"'{ref.experiment}' is not an experiment of this file"
                + did_you_mean(ref.experiment, names),
            )
        for s in e.outputs:
            seen = form_of.setdefault(s, (is_ratio(e), e.name))
            if seen[0] != is_ratio(e):
                raise spec.error(
                    (*e.path, "reference", "form") if e.reference else (*e.path, "outputs"),
                    f"'{s}' is measured as a ratio in one of experiments '{seen[1]}', "
                    f"'{e.name}' and in its unit in the other: one noise per signal needs one "
                    "form (measure both as ratios, or both in the signal's unit)",
                )


def output_unit(exp, model: Model, signal: str) -> str:
    """The SI unit of ``signal``'s data column and noise in experiment ``exp``."""
    return "1" if is_ratio(exp) else model.variables[signal].unit


def relative_label(exp, signal: str) -> str:
    """How experiment ``exp`` measures ``signal``: ``"myofibril.length / reference"``."""
    ref = exp.reference
    if ref is None:
        return signal
    return f"{signal} {'/' if ref.form == 'ratio' else '-'} reference"


def reference_inputs(spec, ref: ReferenceSpec, model: Model, u0: np.ndarray) -> np.ndarray:
    """The reference's input vector: ``u0`` with the reference's ``inputs`` (SI), each
    checked (an input of ``model``, a quantity in its unit, inside its range)."""
    u = np.array(u0, dtype=float)
    for name, raw in ref.inputs.items():
        path = (*ref.path, "inputs", name)
        target = INPUT_ALIASES.get(name, name)
        if target not in model.input_names:
            hint = did_you_mean(name, [*INPUT_ALIASES, *model.input_names])
            raise spec.error(path, f"'{name}' is not an input of model '{model.name}'{hint}")
        unit = model.variables[target].unit
        try:
            value = to_si(raw, unit, name, bare_ok=False)
        except ParameterError as exc:
            raise spec.error(path, f"{raw!r}: {exc.allowed} ({unit})") from None
        if target == "regulator.p_cmd":
            lo, hi = command_range(model, {})
        else:
            lo, hi = model.variables[target].low, model.variables[target].high
        if not lo <= value <= hi:
            raise spec.error(path, f"{raw!r} is outside the input's range [{lo:g}, {hi:g}] {unit}")
        u[model.input_names.index(target)] = value
    return u


def relative(point: str, reference: str, signal: str, value: float, form: str) -> Target:
    """The target "``signal`` of ``point`` against the same signal of ``reference``
    (``form``: ratio or difference) measured as ``value``"."""

    def expr(sig):
        y, y_ref = sig(point, signal), sig(reference, signal)
        return y / y_ref if form == "ratio" else y - y_ref

    return Target(f"{point}:{signal}", expr, value, signal)


__all__ = [
    "FORMS",
    "ReferenceSpec",
    "check_references",
    "is_ratio",
    "output_unit",
    "parse_reference",
    "reference_inputs",
    "relative",
    "relative_label",
]
