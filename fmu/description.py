"""``modelDescription.xml`` from the model's names, units and bounds (FMI 2.0 and 3.0).

Units become FMI unit definitions with SI base-unit exponents (through pint); the
structure (outputs' and derivatives' dependencies) comes from the sparsity of the exact
Jacobians, so it lists what each one really depends on.

Value references, in both FMI versions: 0 is ``time`` (a variable of FMI 3.0 only, as in
the Reference FMUs: no output depends on value reference 0, which OMSimulator requires),
the model's variables follow from 1 in :class:`~.export.Layout` order (:func:`vr`).
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from importlib import metadata

import pint

from sarcomere.dynamics.errors import ParameterError

_BASE = {
    "[mass]": "kg",
    "[length]": "m",
    "[time]": "s",
    "[current]": "A",
    "[temperature]": "K",
    "[substance]": "mol",
    "[luminosity]": "cd",
}

TIME_VR = 0
"""Value reference of ``time`` (FMI 3.0; unused in FMI 2.0)."""


def vr(position: int) -> int:
    """The value reference of the variable at ``position`` in the layout."""
    return TIME_VR + 1 + position


LOG_CATEGORIES = {
    "logStatusError": "errors: refused calls, failed Newton iterations, left physical domains",
    "logStatusWarning": "warnings",
    "logSolver": "equilibrium at initialisation and Radau substeps of each doStep",
    "logCalls": "every FMI call",
}
"""The log categories of the C wrapper (``instance.c``), in its order."""


@functools.cache
def _ureg() -> pint.UnitRegistry:
    return pint.UnitRegistry()


def base_units(unit: str) -> dict[str, str]:
    """The attributes of an FMI ``BaseUnit`` for an SI unit string ("Pa" ->
    ``{"kg": "1", "m": "-1", "s": "-2"}``); "rad" counts as the base unit rad."""
    if unit == "rad":
        return {"rad": "1"}
    try:
        q = _ureg().Quantity(1.0, "dimensionless" if unit == "1" else unit).to_base_units()
    except pint.PintError as exc:
        raise ParameterError("unit", unit, "a unit pint knows", str(exc)) from None
    out = {}
    for dim, exp in q.dimensionality.items():
        if dim not in _BASE or exp != int(exp):
            raise ParameterError("unit", unit, "a product of integer powers of SI base units")
        out[_BASE[dim]] = str(int(exp))
    if not math.isclose(q.magnitude, 1.0, rel_tol=1e-12):
        out["factor"] = repr(q.magnitude)
    return out


def _num(v: float) -> str:
    return repr(float(v))


def _dependencies(deps: list[list[int]], ref) -> list[str]:
    """Layout positions as attribute text, each mapped by ``ref`` (FMI 2.0: the 1-based
    ScalarVariable index; FMI 3.0: the value reference, :func:`vr`)."""
    return [" ".join(str(ref(i)) for i in row) for row in deps]


def _index(position: int) -> int:
    """FMI 2.0 ScalarVariable index (1-based position in ``ModelVariables``)."""
    return position + 1


def _text(root: ET.Element) -> str:
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode")


def model_description(lay, fmi_version: int, ident: str, guid: str, sources, experiment) -> str:
    """The model description of the FMU (FMI 2.0 or 3.0) as a string."""
    if fmi_version == 2:
        return _text(_fmi2(lay, ident, guid, sources, experiment))
    return _text(_fmi3(lay, ident, guid, experiment))


def build_description(ident: str, sources) -> str:
    """FMI 3.0 ``sources/buildDescription.xml``: the C files to compile."""
    root = ET.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    config = ET.SubElement(root, "BuildConfiguration", {"modelIdentifier": ident})
    files = ET.SubElement(config, "SourceFileSet", {"language": "C11"})
    for f in sources:
        ET.SubElement(files, "SourceFile", {"name": f})
    return _text(root)


def _header(lay, version_attrs: dict, guid_key: str, guid: str) -> ET.Element:
    attrs = {
        **version_attrs,
        "modelName": lay.name,
        guid_key: guid,
        "description": lay.text,
        "generationTool": f"sarcomere {metadata.version('sarcomere')}",
        "variableNamingConvention": "structured",
    }
    return ET.Element("fmiModelDescription", attrs)


def _units(root: ET.Element, lay, extra: tuple[str, ...] = ()) -> None:
    units = ET.SubElement(root, "UnitDefinitions")
    for unit in sorted({v[2] for v in lay.variables} | set(extra)):
        el = ET.SubElement(units, "Unit", {"name": unit})
        ET.SubElement(el, "BaseUnit", base_units(unit))


def _log_categories(root: ET.Element) -> None:
    cats = ET.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES.items():
        ET.SubElement(cats, "Category", {"name": name, "description": text})


def _experiment(root: ET.Element, experiment) -> None:
    attrs = {"startTime": _num(experiment.start_time), "stepSize": _num(experiment.step_size)}
    if experiment.stop_time is not None:
        attrs["stopTime"] = _num(experiment.stop_time)
    ET.SubElement(root, "DefaultExperiment", attrs)


_CAUSALITY = {"x": "local", "der": "local", "u": "input", "y": "output", "p": "parameter"}


def _type_attrs(lay, i: int, row: tuple, fmi_version: int) -> dict:
    name, group, unit, start, low, high, nominal, _ = row
    attrs = {"unit": unit}
    if group == "der":
        nx = lay.count("x")
        state = i - nx  # the state's position
        attrs["derivative"] = str(_index(state) if fmi_version == 2 else vr(state))
    if math.isfinite(low):
        attrs["min"] = _num(low)
    if math.isfinite(high):
        attrs["max"] = _num(high)
    if nominal is not None and group in ("x", "u", "p"):
        attrs["nominal"] = _num(nominal)
    if start is not None:
        attrs["start"] = _num(start)
    return attrs


def _var_attrs(lay, i: int, row: tuple, vr_key: str) -> dict:
    name, group, *_, text = row
    attrs = {"name": name, vr_key: str(vr(i)), "description": text}
    attrs["causality"] = _CAUSALITY[group]
    sampled = lay.sample_period is not None
    if group == "p":
        attrs["variability"] = "tunable" if name in lay.tunable else "fixed"
    elif sampled and group in ("x", "y"):
        attrs["variability"] = "discrete"  # changes at the sample instants only
    else:
        attrs["variability"] = "continuous"
    if group == "x":
        attrs["initial"] = "exact" if sampled else "approx"
    elif group == "p":
        attrs["initial"] = "exact"
    return attrs


def _interfaces(lay) -> tuple[str, ...]:
    """A sampled system has no continuous-time form: Co-Simulation only."""
    return ("CoSimulation",) if lay.sample_period is not None else ("ModelExchange", "CoSimulation")


def _fmi2(lay, ident: str, guid: str, sources, experiment) -> ET.Element:
    root = _header(lay, {"fmiVersion": "2.0"}, "guid", guid)
    root.set("numberOfEventIndicators", "0")
    caps = {
        "modelIdentifier": ident,
        "providesDirectionalDerivative": str(lay.sample_period is None).lower(),
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true",
        "canNotUseMemoryManagementFunctions": "true",
    }
    for kind in _interfaces(lay):
        extra = {"canHandleVariableCommunicationStepSize": "true"} if kind == "CoSimulation" else {}
        el = ET.SubElement(root, kind, {**caps, **extra})
        if sources:  # none: a law calling DAQP, whose sources are not in the archive
            files = ET.SubElement(el, "SourceFiles")
            for f in sources:
                ET.SubElement(files, "File", {"name": f})
    _units(root, lay)
    _log_categories(root)
    _experiment(root, experiment)
    mv = ET.SubElement(root, "ModelVariables")
    for i, row in enumerate(lay.variables):
        sv = ET.SubElement(mv, "ScalarVariable", _var_attrs(lay, i, row, "valueReference"))
        ET.SubElement(sv, "Real", _type_attrs(lay, i, row, 2))
    ms = ET.SubElement(root, "ModelStructure")
    first_y = lay.first("y")
    outs = ET.SubElement(ms, "Outputs")
    for k, dep in enumerate(_dependencies(lay.y_dep, _index)):
        ET.SubElement(outs, "Unknown", {"index": str(_index(first_y + k)), "dependencies": dep})
    if lay.f_dep:
        first_der = lay.first("der")
        ders = ET.SubElement(ms, "Derivatives")
        for k, dep in enumerate(_dependencies(lay.f_dep, _index)):
            attrs = {"index": str(_index(first_der + k)), "dependencies": dep}
            ET.SubElement(ders, "Unknown", attrs)
    init = ET.SubElement(ms, "InitialUnknowns")
    for i, row in enumerate(lay.variables):
        if row[1] in _initial_unknowns(lay):
            ET.SubElement(init, "Unknown", {"index": str(_index(i))})
    return root


def _initial_unknowns(lay) -> tuple[str, ...]:
    """Groups computed at initialisation (a sampled system's states start as given)."""
    return ("y",) if lay.sample_period is not None else ("x", "der", "y")


def _fmi3(lay, ident: str, guid: str, experiment) -> ET.Element:
    root = _header(lay, {"fmiVersion": "3.0"}, "instantiationToken", guid)
    caps = {
        "modelIdentifier": ident,
        "providesDirectionalDerivatives": str(lay.sample_period is None).lower(),
        "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true",
    }
    for kind in _interfaces(lay):
        extra = {"canHandleVariableCommunicationStepSize": "true"}
        if kind == "ModelExchange":
            extra = {"needsCompletedIntegratorStep": "true"}
        ET.SubElement(root, kind, {**caps, **extra})
    _units(root, lay, ("s",))
    _log_categories(root)
    _experiment(root, experiment)
    mv = ET.SubElement(root, "ModelVariables")
    time = {"name": "time", "valueReference": str(TIME_VR)}
    time.update(causality="independent", variability="continuous", unit="s")
    ET.SubElement(mv, "Float64", {**time, "description": "simulation time"})
    for i, row in enumerate(lay.variables):
        attrs = _var_attrs(lay, i, row, "valueReference")
        attrs.update(_type_attrs(lay, i, row, 3))
        ET.SubElement(mv, "Float64", attrs)
    ms = ET.SubElement(root, "ModelStructure")
    first_y = lay.first("y")
    for k, dep in enumerate(_dependencies(lay.y_dep, vr)):
        ET.SubElement(ms, "Output", {"valueReference": str(vr(first_y + k)), "dependencies": dep})
    for k, dep in enumerate(_dependencies(lay.f_dep, vr)):
        attrs = {"valueReference": str(vr(lay.first("der") + k)), "dependencies": dep}
        ET.SubElement(ms, "ContinuousStateDerivative", attrs)
    # stated, not left to the default (all knowns): CasADi's DaeBuilder cannot read the
    # default; the start states are the equilibrium of the inputs and parameters
    knowns = " ".join(str(vr(i)) for i, row in enumerate(lay.variables) if row[1] in ("u", "p"))
    for i, row in enumerate(lay.variables):
        if row[1] in _initial_unknowns(lay):
            attrs = {"valueReference": str(vr(i))}
            if knowns:
                attrs["dependencies"] = knowns
            ET.SubElement(ms, "InitialUnknown", attrs)
    return root
