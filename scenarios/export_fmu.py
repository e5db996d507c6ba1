"""``sarcomere export-fmu SCENARIO --fmi 2|3 --out X.fmu``: a transient scenario's model as
an FMU (Model Exchange and Co-Simulation in one archive; see docs/fmu.md).

The FMU carries the scenario's model (set-up, n, fidelity, ``[parameters]``) with its
start inputs (the input signals at ``start_time``) and ``[simulation]`` as the default
experiment; its states start at the equilibrium there. The input signals themselves stay
with the importer.

``--out``: a missing parent folder is created (as ``run`` does); an existing file is
replaced only if it is an FMU (a zip archive with a ``modelDescription.xml``) or with
``--force``; a folder is refused.
"""

from __future__ import annotations

import argparse
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

from sarcomere.dynamics.errors import ParameterError

if TYPE_CHECKING:
    # the model and the exporter are imported when used: CLI start-up
    from sarcomere.dynamics.modeling.model import Model
    from sarcomere.fmu.export import Experiment

    from .spec import Scenario


def scenario_setup(source: str | Path | Scenario) -> tuple[Model, dict, dict, Experiment]:
    """The model, parameter overrides, start inputs and default experiment of a transient
    scenario (file, packaged name or loaded :class:`Scenario`)."""
    from sarcomere.dynamics.assemblies import FIDELITIES
    from sarcomere.fmu.export import DEFAULT_STEP_S, Experiment

    from .binding import bind, check_n, scene_inputs
    from .loader import load_scenario
    from .spec import Scenario

    sc = source if isinstance(source, Scenario) else load_scenario(source)
    if sc.kind != "transient":
        raise sc.error(("scenario", "kind"), f"'{sc.kind}': an FMU is exported from a transient")
    fid = sc.model.fidelity
    if fid not in FIDELITIES:
        raise sc.error(("model", "fidelity"), f"'{fid}': an FMU is exported at one level")
    b = bind(sc)
    check_n(sc, ("model", "n"), b.n, fid)
    model = b.build(fid)
    sim = sc.simulation
    if sim is None:
        raise sc.error(("simulation",), "a transient needs [simulation] stop_time")
    inputs = {k: float(sig(sim.start_time)) for k, sig in scene_inputs(sc, model).items()}
    experiment = Experiment(sim.start_time, sim.stop_time, sim.output_interval or DEFAULT_STEP_S)
    return model, dict(b.overrides), inputs, experiment


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``SCENARIO``, ``--fmi 2|3`` (default 2), ``--out X.fmu`` (default <model>.fmu) and
    ``--parameters FILE``."""
    parser.add_argument("scenario", help="scenario file (path/to/file.toml) or packaged name")
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version")
    parser.add_argument("--out", metavar="X.fmu", help="the FMU to write (default <name>.fmu)")
    parser.add_argument(
        "--force", action="store_true", help="replace --out even if it is not an FMU"
    )
    from .cli import parameters_argument

    parameters_argument(parser)


def _is_fmu(path: Path) -> bool:
    """A zip archive holding a ``modelDescription.xml``: what an export may replace."""
    if not zipfile.is_zipfile(path):
        return False
    try:
        with zipfile.ZipFile(path) as zf:
            return "modelDescription.xml" in zf.namelist()
    except (zipfile.BadZipFile, OSError):
        return False


def check_output(out: Path, force: bool) -> None:
    """``out`` checked for an export: a ``.fmu`` name, not a folder, an existing file only
    if it is an FMU (or with ``force``)."""
    if out.is_dir():
        raise ParameterError("--out", str(out), "a file name ending in .fmu", "it is a folder")
    if out.suffix != ".fmu":
        raise ParameterError("--out", str(out), "a file name ending in .fmu")
    if out.exists() and not force and not _is_fmu(out):
        raise ParameterError(
            "--out",
            str(out),
            "a new file or an existing FMU",
            "the file exists and is not an FMU; --force replaces it",
        )


def handler(args: argparse.Namespace) -> int:
    """Export and print the path written."""
    from sarcomere.fmu.export import export_fmu

    from .loader import load_scenario

    sc = load_scenario(args.scenario)
    if args.parameters is not None:
        from .loader import with_parameter_file

        sc = with_parameter_file(sc, args.parameters)
    out = Path(args.out) if args.out else Path(f"{sc.name}.fmu")
    check_output(out, args.force)
    model, params, inputs, experiment = scenario_setup(sc)
    out.parent.mkdir(parents=True, exist_ok=True)  # as `run` creates its folder
    export_fmu(model, out, args.fmi, params, inputs, experiment)
    print(f"wrote {out} ({model.describe()}; FMI {args.fmi}.0, Model Exchange and Co-Simulation)")
    return 0
