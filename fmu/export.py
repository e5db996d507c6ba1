"""Export a flattened model as one FMU holding Model Exchange and Co-Simulation.

The pipeline: the model's CasADi Functions are generated to C (:mod:`.codegen`), the
variable tables and sizes are written as ``model_data.h``/``model_data.c``, the model
description is written from the model's names (:mod:`.description`), the project's FMI
wrapper (``fmu/c/``: ``fmi2.c`` or ``fmi3.c`` over ``instance.c`` over ``physics.c``) is
compiled with the system C compiler into ``binaries/<platform>/<model>.so`` (this
machine's platform: linux64, or x86_64-linux for FMI 3.0), and everything,
sources included, is zipped into the ``.fmu``.

Value references are the variables' positions in one list (states, state derivatives,
inputs, outputs, parameters; see :class:`Layout`) plus one: 0 is ``time``
(:data:`.description.TIME_VR`), which no output depends on.
"""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import casadi as cs
import fmpy
import numpy as np

from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError, SarcomereError, SolverError
from sarcomere.dynamics.modeling.model import Model

from . import codegen, description

FMI_VERSIONS = (2, 3)

DEFAULT_STEP_S = 1e-3
"""Step size of the default experiment [s]. A Co-Simulation ``doStep`` of any size meets
its tolerance by the adaptive Radau IIA inside (:mod:`.codegen`: ``CS_RTOL``)."""

EQ_TOL = 1e-10
"""Largest accepted scaled residual of the initial equilibrium [-] (as
:func:`~sarcomere.dynamics.equilibrium.solve_equilibrium`)."""

EQ_MIN_FRACTION = 1.0 / 1024
"""Smallest continuation step of the initial equilibrium in C (fraction of the way from
the exported operating point to the inputs and parameters set)."""

SAMPLE_TOL = 1e-6
"""A sampled system's instant ``k T`` lies in a ``doStep`` interval ``[t, t + h)`` when
``t / T - SAMPLE_TOL <= k < (t + h) / T - SAMPLE_TOL`` [-, fraction of a period]: times
that accumulate rounding errors still hit their sample."""

MAX_SAMPLES = 1000
"""Most sample instants a sampled system's ``doStep`` runs (a longer step is refused with a
message, as a continuous model's ``doStep`` stops after ``codegen.CS_MAX_STEPS`` internal
steps): all of them see the same held inputs, and an NMPC law costs about 10 ms a sample,
so one call stays below some 10 s."""

C_SOURCES = ("physics.c", "instance.c", "registry.c")
C_HEADERS = ("physics.h", "instance.h")


class FmuError(SarcomereError):
    """The FMU could not be built (the compiler failed, or the model cannot be exported)."""


@dataclass(frozen=True)
class Experiment:
    """``DefaultExperiment`` of the model description [s]."""

    start_time: float = 0.0
    stop_time: float | None = None
    step_size: float = DEFAULT_STEP_S


@dataclass(frozen=True)
class Layout:
    """Every FMU variable in value-reference order, with its metadata: all the model
    description and the C tables need.

    Each row of ``variables`` is ``(name, group, unit, start, low, high, nominal,
    description)``; ``group`` is "x" (state), "der" (its derivative), "u", "y" or "p".
    ``start`` is None where the variable has no start value (derivatives, outputs).
    ``tunable``: the parameters no start value depends on (see :func:`tunable`).
    ``y_dep``, ``f_dep``: for each output and each derivative, the positions in
    ``variables`` of the states and inputs it depends on. ``sample_period`` [s]: None for
    a continuous model, else the period of a sampled system (discrete states, no derivatives,
    Co-Simulation only; :mod:`.sampled`). ``pwm``: None, or ``(input index, period [s],
    min_on [s], delay [s], averaged)`` of a PWM-modulated input (:attr:`Model.modulators`),
    which the Co-Simulation's doStep switches (``physics.c``; Model Exchange takes the
    input as the valve's command).
    """

    name: str
    text: str
    variables: list[tuple] = field(default_factory=list)
    tunable: frozenset[str] = frozenset()
    y_dep: list[list[int]] = field(default_factory=list)
    f_dep: list[list[int]] = field(default_factory=list)
    sample_period: float | None = None
    pwm: tuple | None = None

    def first(self, group: str) -> int:
        """Position in ``variables`` of the first variable of ``group``."""
        return next(i for i, v in enumerate(self.variables) if v[1] == group)

    def count(self, group: str) -> int:
        """How many variables ``group`` has."""
        return sum(v[1] == group for v in self.variables)


def _derivative_unit(unit: str) -> str:
    if unit == "1":
        return "1/s"
    if unit.endswith("/s"):
        return unit + "^2"
    return f"{unit}/s"


def tunable(model: Model) -> frozenset[str]:
    """The parameters that are safe to change after initialisation: those no start value
    depends on (a change of the others would leave the states inconsistent with the
    geometry they were computed from: thread lengths, volumes, ambient state)."""
    starts = cs.vertcat(*model.function("start")(model.p))
    used = set(cs.jacobian(starts, model.p).sparsity().get_col())
    return frozenset(n for i, n in enumerate(model.param_names) if i not in used)


def dependencies(model: Model, expr: cs.SX, first_u: int) -> list[list[int]]:
    """For each row of ``expr``: the positions (in :attr:`Layout.variables`) of the states
    and inputs it uses (from the sparsity of its exact Jacobian); the inputs start at
    ``first_u``."""
    known = cs.vertcat(model.x, model.u)
    columns = [*range(model.nx), *range(first_u, first_u + len(model.input_names))]
    sp = cs.jacobian(expr, known).sparsity()
    rows: list[list[int]] = [[] for _ in range(expr.numel())]
    for r, c in zip(sp.row(), sp.get_col(), strict=True):
        rows[r].append(columns[c])
    return [sorted(r) for r in rows]


def layout(model: Model, x0: np.ndarray, u0: np.ndarray, p: np.ndarray) -> Layout:
    """The variables of the FMU of ``model``, with start values ``x0``, ``u0`` and ``p``."""
    m = model
    rows = []
    for i, n in enumerate(m.state_names):
        v = m.variables[n]
        rows.append((n, "x", v.unit, x0[i], v.low, v.high, v.nominal, v.description))
    for n in m.state_names:
        v = m.variables[n]
        unit = _derivative_unit(v.unit)
        rows.append((f"der({n})", "der", unit, None, -math.inf, math.inf, None, f"d/dt {n}"))
    for i, n in enumerate(m.input_names):
        v = m.variables[n]
        rows.append((n, "u", v.unit, u0[i], v.low, v.high, v.nominal, v.description))
    for n in m.output_names:
        v = m.variables[n]
        rows.append((n, "y", v.unit, None, v.low, v.high, v.nominal, v.description))
    for i, n in enumerate(m.param_names):
        v = m.variables[n]
        rows.append((n, "p", v.unit, p[i], v.low, v.high, v.nominal, v.description))
    nothing = cs.SX(0, 1)
    first_u = 2 * m.nx
    y_dep = dependencies(m, m.function("y")(m.x, nothing, m.u, m.p), first_u)
    f_dep = dependencies(m, m.function("ode")(m.x, nothing, m.u, m.p), first_u)
    pwm = None
    if m.modulators:
        if len(m.modulators) > 1:
            raise ParameterError("model", m.name, "at most one PWM-modulated input")
        ((name, mod),) = m.modulators.items()
        pwm = (
            m.input_names.index(name),
            mod.period,
            mod.min_on,
            mod.delay,
            mod.level == "averaged",
        )
    return Layout(m.name, m.describe(), rows, tunable(m), y_dep, f_dep, pwm=pwm)


def _c_double(v: float) -> str:
    if math.isinf(v):
        return "INFINITY" if v > 0 else "-INFINITY"
    return repr(float(v))


def _c_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _c_array(ctype: str, name: str, values: list[str]) -> str:
    body = ",\n    ".join(values)
    return f"const {ctype} {name}[{len(values)}] = {{\n    {body}\n}};\n"


def model_data(lay: Layout, gen: codegen.Generated, guid: str, fmi_version: int) -> tuple[str, str]:
    """``model_data.h`` and ``model_data.c``: sizes, value references, tables, tolerances.

    The tables are indexed by value reference: row 0 is ``time`` (``SM_VR_TIME``, a
    variable of the FMI 3.0 description only: ``SM_HAS_TIME_VR``), then the variables."""
    vr = description.vr
    nx, nder, nu = lay.count("x"), lay.count("der"), lay.count("u")
    ny, np_ = lay.count("y"), lay.count("p")
    sampled = lay.sample_period is not None
    defines = {
        "SM_MODEL_NAME": _c_string(lay.name),
        "SM_SAMPLED": int(sampled),
        "SM_SAMPLE_PERIOD": repr(lay.sample_period or 0.0),
        "SM_SAMPLE_TOL": repr(SAMPLE_TOL),
        "SM_MAX_SAMPLES": MAX_SAMPLES,
        "SM_SHARED_MEMORY": int(gen.shared_memory),
        "SM_ADVANCE_UNIT": _c_string("samples" if sampled else "Radau IIA steps"),
        "SM_NX": nx,
        "SM_NU": nu,
        "SM_NY": ny,
        "SM_NP": np_,
        "SM_VR_TIME": description.TIME_VR,
        "SM_VR_X": vr(0),
        "SM_VR_DER": vr(nx),
        "SM_VR_U": vr(nx + nder),
        "SM_VR_Y": vr(nx + nder + nu),
        "SM_VR_P": vr(nx + nder + nu + ny),
        "SM_NVARS": len(lay.variables),
        "SM_HAS_TIME_VR": int(fmi_version == 3),
        "SM_SZ_ARG": gen.sz_arg,
        "SM_SZ_RES": gen.sz_res,
        "SM_SZ_IW": gen.sz_iw,
        "SM_SZ_W": gen.sz_w,
        "SM_GUID": _c_string(guid),
        "SM_EQ_TOL": repr(EQ_TOL),
        "SM_EQ_ITERATIONS": codegen.EQ_NEWTON_ITERATIONS,
        "SM_EQ_MIN_FRACTION": repr(EQ_MIN_FRACTION),
        "SM_PWM": int(lay.pwm is not None),
    }
    if lay.pwm is not None:
        index, period, min_on, delay, averaged = lay.pwm
        defines |= {
            "SM_PWM_INPUT": index,
            "SM_PWM_PERIOD": repr(period),
            "SM_PWM_MIN_ON": repr(min_on),
            "SM_PWM_DELAY": repr(delay),
            "SM_PWM_AVERAGED": int(averaged),
        }
    h = [
        f"/* Generated by sarcomere for model '{lay.name}': sizes and tables of the FMU. */",
        "#ifndef SM_MODEL_DATA_H",
        "#define SM_MODEL_DATA_H",
        "",
    ]
    h += [f"#define {k} {v}" for k, v in defines.items()]
    h += [
        "",
        "extern const char* const sm_names[SM_NVARS + 1];",
        "extern const double sm_min[SM_NVARS + 1];",
        "extern const double sm_max[SM_NVARS + 1];",
        "extern const double sm_x_start[SM_NX]; /* the equilibrium at the start point */",
        "extern const double sm_u_start[SM_NU];",
        "extern const double sm_p_start[SM_NP];",
        "extern const double sm_x_nominal[SM_NX];",
        "extern const int sm_tunable[SM_NP]; /* settable in step and event mode */",
        "",
        "#endif",
        "",
    ]
    rows = lay.variables
    group = {g: [r for r in rows if r[1] == g] for g in ("x", "u", "p")}
    c = [
        f"/* Generated by sarcomere for model '{lay.name}': the variable tables. */",
        "#include <math.h>",
        "",
        '#include "model_data.h"',
        "",
        _c_array("char* const", "sm_names", ['"time"'] + [_c_string(r[0]) for r in rows]),
        _c_array("double", "sm_min", ["-INFINITY"] + [_c_double(r[4]) for r in rows]),
        _c_array("double", "sm_max", ["INFINITY"] + [_c_double(r[5]) for r in rows]),
        _c_array("double", "sm_x_start", [_c_double(r[3]) for r in group["x"]]),
        _c_array("double", "sm_u_start", [_c_double(r[3]) for r in group["u"]]),
        _c_array("double", "sm_p_start", [_c_double(r[3]) for r in group["p"]]),
        _c_array("double", "sm_x_nominal", [_c_double(r[6] or 1.0) for r in group["x"]]),
        _c_array("int", "sm_tunable", [str(int(r[0] in lay.tunable)) for r in group["p"]]),
    ]
    return "\n".join(h), "\n".join(c)


def _guid(lay: Layout, fmi_version: int) -> str:
    text = repr((lay.name, fmi_version, lay.variables, lay.sample_period)).encode()
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, hashlib.sha256(text).hexdigest())) + "}"


def fmi_headers() -> Path:
    """The folder of the official FMI headers (shipped inside fmpy, ``c-code/``)."""
    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise FmuError(f"the FMI headers are not in {folder}; reinstall fmpy")
    return folder


def compile_binary(src: Path, out: Path, fmi_version: int) -> None:
    """Compile the sources in ``src`` into the shared library ``out`` with gcc."""
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        raise FmuError("no C compiler: install gcc or set CC")
    sources = [str(f) for f in sorted(src.glob("*.c"))]  # fmi<version>.c, the physics
    cmd = [cc, "-shared", "-fPIC", "-O2", *codegen.CFLAGS, "-fvisibility=hidden", "-std=c11"]
    cmd += ["-I", str(src), "-I", str(fmi_headers()), *sources, "-o", str(out)]
    cmd += [*qp_libraries(src), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise FmuError(f"the C compiler failed ({' '.join(cmd[:6])} ...): {done.stderr[-2000:]}")


def calls_daqp(src: Path) -> bool:
    """Whether the generated sources in ``src`` call DAQP (a controller FMU's law)."""
    return any("<daqp/api.h>" in f.read_text() for f in src.glob("sm_*.c"))


def qp_libraries(src: Path) -> list[str]:
    """The compiler arguments for a generated QP solver the sources call (a controller
    FMU's law): DAQP's headers and static library as the casadi wheel ships them."""
    if not calls_daqp(src):
        return []
    from sarcomere.controllers.rti_compiled import daqp_build

    try:
        include, link = daqp_build()
    except SolverError as exc:
        raise FmuError(f"the law calls DAQP: {exc}") from None
    return [*include, *link]


def check_target(path: str | Path, fmi_version: int) -> Path:
    """``path`` as a Path, checked: a ``.fmu`` file in an existing folder; and the version."""
    if fmi_version not in FMI_VERSIONS:
        raise ParameterError("fmi_version", fmi_version, "2 or 3")
    path = Path(path)
    if path.suffix != ".fmu":
        raise ParameterError("path", str(path), "a file name ending in .fmu")
    if not path.parent.is_dir():
        raise ParameterError("path", str(path), "a file in an existing folder")
    return path


def start_point(
    model: Model, params: Mapping[str, object] | None, inputs: Mapping[str, float] | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x0, u0, p)``: the equilibrium at the start inputs (by name; default the model's
    start values) and parameters (defaults with ``params`` overrides)."""
    p = model.parameters(params)
    u = model.u0(p)
    for k, v in (inputs or {}).items():
        if k not in model.input_names:
            raise ParameterError("inputs", k, f"an input of model '{model.name}'")
        var = model.variables[k]
        if not var.contains(float(v)):
            raise var.refuse(k, v)
        u[model.input_names.index(k)] = float(v)
    eq = solve_equilibrium(model, dict(zip(model.input_names, u, strict=True)), params)
    return eq.x, u, p


def export_fmu(
    model: Model,
    path: str | Path,
    fmi_version: int = 2,
    params: Mapping[str, object] | None = None,
    inputs: Mapping[str, float] | None = None,
    experiment: Experiment | None = None,
) -> Path:
    """Write an FMU (Model Exchange and Co-Simulation, linux64 binary and C sources).

    Parameters
    ----------
    model : Model
        A flattened model (``nz = 0``). A scenario's model, parameters, start inputs and
        experiment come from :func:`sarcomere.scenarios.export_fmu.scenario_setup` (what
        ``sarcomere export-fmu`` does).
    path : str or Path
        The ``.fmu`` file to write (its folder must exist).
    fmi_version : int
        2 or 3.
    params, inputs : mapping, optional
        Parameter overrides and start inputs by name: the FMU's start values, and the
        operating point its start states are the equilibrium of.
    experiment : Experiment, optional
        The default experiment.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        For a bad model, version, path, parameter or input.
    FmuError
        If the C compiler fails.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from sarcomere.dynamics.assemblies import hanging_load
    >>> from sarcomere.fmu import export_fmu
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "hanging.fmu"
    >>> export_fmu(hanging_load(1, load_kg=0.05), out).stat().st_size > 10_000
    True
    """
    if not isinstance(model, Model):
        raise ParameterError(
            "model",
            model,
            "a flattened Model",
            "a scenario's model is built by sarcomere.scenarios.export_fmu.scenario_setup",
        )
    path = check_target(path, fmi_version)
    codegen.require_ode(model)
    for what, names in (("inputs", model.input_names), ("outputs", model.output_names)):
        if not names:
            raise ParameterError("model", model.name, f"a model with {what}")
    x0, u0, p = start_point(model, params, inputs)
    lay = layout(model, x0, u0, p)
    return build(lay, codegen.functions(model), path, fmi_version, experiment or Experiment())


def build(
    lay: Layout,
    functions: list[cs.Function],
    path: Path,
    fmi_version: int,
    experiment: Experiment,
) -> Path:
    """Generate, compile and zip the FMU of ``lay`` whose physics are ``functions`` (the
    generated ``sm_*`` Functions :file:`physics.c` calls) into ``path``."""
    guid = _guid(lay, fmi_version)
    ident = lay.name
    with tempfile.TemporaryDirectory(prefix="sarcomere-fmu-") as tmp:
        root = Path(tmp)
        src = root / "sources"
        src.mkdir()
        gen = codegen.generate(functions, src)
        header, data = model_data(lay, gen, guid, fmi_version)
        (src / "model_data.h").write_text(header)
        (src / "model_data.c").write_text(data)
        templates = resources.files("sarcomere.fmu") / "c"
        for name in (*C_SOURCES, *C_HEADERS, f"fmi{fmi_version}.c"):
            (src / name).write_text(templates.joinpath(name).read_text())
        sources = [*C_SOURCES, f"fmi{fmi_version}.c", *gen.sources, "model_data.c"]
        if calls_daqp(src):  # DAQP's sources are not in the archive: declare no rebuild
            sources = []
        xml = description.model_description(lay, fmi_version, ident, guid, sources, experiment)
        (root / "modelDescription.xml").write_text(xml)
        if fmi_version == 3 and sources:
            (src / "buildDescription.xml").write_text(description.build_description(ident, sources))
        # this machine's binary folder and library suffix, as importers look them up
        platform = fmpy.platform if fmi_version == 2 else fmpy.platform_tuple
        binaries = root / "binaries" / platform
        binaries.mkdir(parents=True)
        compile_binary(src, binaries / f"{ident}{fmpy.sharedLibraryExtension}", fmi_version)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
            for f in sorted(root.rglob("*")):
                if f.is_file():
                    zf.write(f, f.relative_to(root).as_posix())
    return path
