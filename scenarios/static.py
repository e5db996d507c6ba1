"""The "static" scenario kind: a pressure sweep through the paper's closed-form model.

Supports ``[model] fidelity = "paper"`` (:func:`sarcomere.dynamics.paper.paper_static`);
the other fidelity levels need an equilibrium solve and belong to the "equilibrium" kind.

Scenario keys read here:

- ``[model]``: ``n``, ``material``, ``geometry`` (``"experimental"`` or ``"fem"``), and
  ``options`` = the fields of :class:`~sarcomere.dynamics.paper.PaperOptions`;
- ``[parameters]``: ``geometry.<name>`` and ``material.<C1|C2|C3|density>`` overrides;
- ``[sweep.pressure]``: the gauge pressures, Pa (the only axis).

Result ``pressure_sweep`` (index ``pressure`` [Pa]): ``F_spa``, ``F_contr`` [N],
``theta`` [rad], ``lambda_jz`` [1], ``h_m`` and ``L_mf`` (free length of the ``n`` units) [m];
thread signals are left out for a geometry without a thread (``"fem"``).

Metrics: ``theta_rest_deg``, ``h_m_mm``, ``rest_length_n3_mm``, ``force_0p1MPa_N``
(``F_contr`` at 0.1 MPa), ``force_spa_0p1MPa_N`` and ``table1_force_<slug>_N`` (the
model's counterpart of Table 1's mean maximum force, FEM geometry) for the three FEM
materials.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError
from sarcomere.dynamics.paper import PaperOptions, paper_static, rest_length, theta_rest
from sarcomere.dynamics.paper_reported import table1_mean_max_force
from sarcomere.dynamics.params import (
    ParameterSet,
    YeohMaterial,
    experimental_geometry,
    fem_geometry,
    get_material,
)
from sarcomere.dynamics.results import Result
from sarcomere.dynamics.units import to_si

from .output import RunOutput, quantity_tag
from .runner import register_runner
from .spec import Scenario, describe, unknown_key

#: ``[model] geometry`` name -> parameter set factory.
GEOMETRIES = {"experimental": experimental_geometry, "fem": fem_geometry}

#: Geometry used when ``[model] geometry`` is left out.
DEFAULT_GEOMETRY = "experimental"

#: Materials of the paper's FEM study (Table 1).
TABLE1_MATERIALS = ("ecoflex_00_30", "elastosil_m4601", "smooth_sil_950")

#: Pressure of the isometric experiment and of the force metrics, Pa.
REPORT_PRESSURE_PA = 0.1e6

#: PaperResult field -> (signal name, SI unit).
SIGNALS = {
    "F_spa_N": ("F_spa", "N"),
    "F_contr_N": ("F_contr", "N"),
    "theta_rad": ("theta", "rad"),
    "lambda_jz": ("lambda_jz", "1"),
    "h_m_m": ("h_m", "m"),
}


def _options(scenario: Scenario) -> PaperOptions:
    """``[model.options]`` as PaperOptions."""
    allowed = [f.name for f in dataclasses.fields(PaperOptions)]
    for key in scenario.model.options:
        if key not in allowed:
            raise scenario.error(("model", "options", key), unknown_key(key, allowed))
    try:
        return PaperOptions(**scenario.model.options)
    except ParameterError as exc:
        raise scenario.error(("model", "options", exc.name), describe(exc)) from None


def _bind(scenario: Scenario) -> tuple[ParameterSet, YeohMaterial]:
    """Geometry and material named by ``[model]``, with ``[parameters]`` applied."""
    model = scenario.model
    geometry_name = model.geometry or DEFAULT_GEOMETRY
    if geometry_name not in GEOMETRIES:
        raise scenario.error(
            ("model", "geometry"), f"'{geometry_name}' is not one of {', '.join(GEOMETRIES)}"
        )
    try:
        material = get_material(model.material)
    except ParameterError as exc:
        raise scenario.error(("model", "material"), describe(exc)) from None
    overrides: dict[str, dict[str, object]] = {"geometry": {}, "material": {}}
    for key, value in scenario.parameters.items():
        group, _, name = key.partition(".")
        if group not in overrides or not name:
            raise scenario.parameter_error(
                key, "kind 'static' takes 'geometry.<name>' and 'material.<name>' overrides"
            )
        overrides[group][name] = value
    geometry = GEOMETRIES[geometry_name]()
    sets = {"geometry": geometry, "material": material.params()}
    for group, values in overrides.items():
        for name, value in values.items():  # a file's quantities need their unit
            unit = sets[group].param(name).unit if sets[group].get(name) is not None else "1"
            try:
                to_si(value, unit, f"{group}.{name}", bare_ok=False)
            except ParameterError as exc:
                raise scenario.parameter_error(f"{group}.{name}", describe(exc)) from None
        try:
            if group == "geometry":
                geometry = geometry.with_overrides(values)
            else:
                new = material.params().with_overrides(values)
                material = dataclasses.replace(material, **{k: new[k] for k in values})
        except ParameterError as exc:
            if exc.name in values:
                raise scenario.parameter_error(f"{group}.{exc.name}", describe(exc)) from None
            raise scenario.parameter_error(group, str(exc)) from None  # a cross check
    return geometry, material


def run_static(scenario: Scenario, out_dir: Path) -> RunOutput:
    """Sweep pressure through the paper's static model; see the module docstring.

    Parameters
    ----------
    scenario : Scenario
        Kind ``"static"``, fidelity ``"paper"``, one sweep axis ``pressure``.
    out_dir : pathlib.Path
        Output folder (unused: all outputs go through the RunOutput).

    Returns
    -------
    RunOutput
    """
    if scenario.model.fidelity != "paper":
        raise scenario.error(
            ("model", "fidelity"),
            "kind 'static' evaluates the paper's closed-form model: use fidelity = 'paper' "
            "(other levels need an equilibrium solve)",
        )
    scenario.refuse_unused(
        "inputs", "simulation", "solver", "outputs.tolerance", "control", "cosim"
    )
    axis = scenario.axis("pressure")
    if len(scenario.sweep) > 1:
        raise scenario.error(("sweep",), "kind 'static' sweeps 'pressure' only")
    options = _options(scenario)
    geometry, material = _bind(scenario)
    pressure = np.asarray(axis.values)
    try:
        res = paper_static(pressure, geometry, material, options)
        at_report = paper_static(np.array([REPORT_PRESSURE_PA]), geometry, material, options)
    except ParameterError as exc:
        raise scenario.error(("sweep", "pressure"), f"paper model: {exc}") from None
    signals = {name: res[field] for field, (name, _) in SIGNALS.items() if res[field] is not None}
    units = {name: unit for field, (name, unit) in SIGNALS.items() if res[field] is not None}
    tag = quantity_tag(REPORT_PRESSURE_PA / 1e6, "MPa")
    metrics = {"h_m_mm": geometry["h_m"] * 1e3}
    if "l" in geometry:
        signals["L_mf"] = scenario.model.n * (geometry["A"] + 2.0 * res.r1_m)
        units["L_mf"] = "m"
        metrics["theta_rest_deg"] = math.degrees(theta_rest(geometry, options))
        metrics["rest_length_n3_mm"] = rest_length(3, geometry, options.kinematics) * 1e3
        metrics[f"force_{tag}_N"] = float(at_report.F_contr_N[0])
    metrics[f"force_spa_{tag}_N"] = float(at_report.F_spa_N[0])
    for slug in TABLE1_MATERIALS:
        metrics[f"table1_force_{slug}_N"] = table1_mean_max_force(slug, options)
    result = Result(
        "pressure",
        "Pa",
        pressure,
        signals,
        units,
        meta={"model": "paper_static", "n": scenario.model.n},
    )
    return RunOutput(
        scenario=scenario.name,
        fidelity="paper",
        solver="closed form (bisection for the Yeoh inverse)",
        metrics=metrics,
        results={"pressure_sweep": result},
        extra={
            "options": dataclasses.asdict(options),
            "geometry_m": geometry.values(),
            "material": {
                "slug": material.slug,
                "C1_Pa": material.C1,
                "C2_Pa": material.C2,
                "C3_Pa": material.C3,
            },
        },
    )


register_runner("static", run_static)
