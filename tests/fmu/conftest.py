"""FMUs built once per test session (each export compiles C for a few seconds) and a
loader that captures the FMU's log messages."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Model, FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

from sarcomere.fmu import export_fmu
from sarcomere.scenarios.cli import main
from sarcomere.scenarios.export_fmu import scenario_setup
from sarcomere.scenarios.loader import load_scenario
from sarcomere.scenarios.transient import run_transient

#: A transient isometric scene: one APS on a rigid fixture, a pressure step.
ISOMETRIC_SCENE = """
[scenario]
name = "iso-step"
kind = "transient"
description = "Isometric step 0.01 -> 0.08 MPa, 1 APS on a rigid fixture"

[model]
name = "myofibril"
fidelity = "full"
n = 1

[model.options]
setup = "isometric"

[inputs.pressure]
type = "step"
initial = "0.01 MPa"
final = "0.08 MPa"
time = "0.05 s"

[simulation]
stop_time = "0.5 s"
output_interval = "1 ms"

[solver]
method = "cvodes"
rtol = 1e-8
atol = 1e-12
"""


@pytest.fixture(scope="session")
def step_fmu(tmp_path_factory) -> Path:
    """step-50g's model (n = 3, 50 g) as an FMI 2.0 FMU, exported through the CLI."""
    out = tmp_path_factory.mktemp("fmu") / "step-50g.fmu"
    assert main(["export-fmu", "step-50g", "--fmi", "2", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def iso_scene(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("scene") / "iso-step.toml"
    path.write_text(ISOMETRIC_SCENE)
    return path


@pytest.fixture(scope="session")
def iso_fmu(tmp_path_factory, iso_scene) -> Path:
    """The isometric scene's model (n = 1) as an FMI 2.0 FMU, exported through the API."""
    model, params, inputs, experiment = scenario_setup(iso_scene)
    out = tmp_path_factory.mktemp("fmu") / "iso.fmu"
    return export_fmu(model, out, 2, params, inputs, experiment)


def native(scene, tmp_path: Path):
    """The native simulation of a scene (its main Result)."""
    return run_transient(load_scenario(scene), tmp_path).results["main"]


class Loaded:
    """An unzipped FMU with instances whose log messages are kept in ``messages``."""

    def __init__(self, fmu: Path, folder: Path) -> None:
        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(folder)
        self.folder = folder
        self.md = read_model_description(fmu)
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.messages: list[tuple[int, str, str]] = []

        def log(env, name, status, category, message):
            self.messages.append((status, category.decode(), message.decode()))

        self._logger = fmi2CallbackLoggerTYPE(log)  # kept alive as long as the instances
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = self._logger

    def instance(self, cosim: bool = True, name: str = "instance", logging_on: bool = False):
        cls = FMU2Slave if cosim else FMU2Model
        kind = self.md.coSimulation if cosim else self.md.modelExchange
        fmu = cls(
            guid=self.md.guid,
            unzipDirectory=str(self.folder),
            modelIdentifier=kind.modelIdentifier,
            instanceName=name,
        )
        fmu.instantiate(callbacks=self.callbacks, loggingOn=logging_on)
        return fmu

    def errors(self) -> list[str]:
        return [m for status, _, m in self.messages if status == 3]


@pytest.fixture
def load(tmp_path):
    """``load(fmu)``: the FMU unzipped into a fresh folder, as a :class:`Loaded`."""
    count = iter(range(1000))
    return lambda fmu: Loaded(fmu, tmp_path / f"unzipped{next(count)}")


@pytest.fixture(scope="session")
def step_native(tmp_path_factory):
    """step-50g simulated natively (CVODES, rtol 1e-6, 2 ms output grid)."""
    return native("step-50g", tmp_path_factory.mktemp("native"))


@pytest.fixture(scope="session")
def iso_native(tmp_path_factory, iso_scene):
    return native(iso_scene, tmp_path_factory.mktemp("native"))


@pytest.fixture
def step_loaded(load, step_fmu) -> Loaded:
    return load(step_fmu)


@pytest.fixture(scope="session")
def iso_fmu3(tmp_path_factory, iso_scene) -> Path:
    """The isometric scene's model (n = 1) as an FMI 3.0 FMU, exported through the CLI."""
    out = tmp_path_factory.mktemp("fmu") / "iso3.fmu"
    assert main(["export-fmu", str(iso_scene), "--fmi", "3", "--out", str(out)]) == 0
    return out
