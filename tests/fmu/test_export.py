"""The exported archive: model description from the model's names, validation, sources,
refused arguments, the CLI."""

from __future__ import annotations

import zipfile

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from sarcomere.dynamics.assemblies import hanging_load
from sarcomere.dynamics.equilibrium import solve_equilibrium
from sarcomere.dynamics.errors import ParameterError
from sarcomere.fmu import FmuError, export_fmu
from sarcomere.fmu.description import base_units
from sarcomere.scenarios.cli import main

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)


def test_fmi2_fmus_validate(step_fmu, iso_fmu):
    assert validate_fmu(str(step_fmu)) == []
    assert validate_fmu(str(iso_fmu)) == []


def test_variables_follow_the_model(step_fmu):
    md = read_model_description(step_fmu)
    model = hanging_load(3, load_kg=0.05)
    eq = solve_equilibrium(model, {"regulator.p_cmd": 0.0})
    by_name = {v.name: v for v in md.modelVariables}
    names = [v.name for v in md.modelVariables]
    ders = [f"der({n})" for n in model.state_names]
    expected = model.state_names + ders + model.input_names + model.output_names
    assert names == expected + model.param_names
    assert [v.valueReference for v in md.modelVariables] == list(range(1, len(names) + 1))
    for i, n in enumerate(model.state_names):
        v = by_name[n]
        assert (v.causality, v.variability, v.initial) == ("local", "continuous", "approx")
        assert float(v.start) == pytest.approx(eq.x[i], rel=1e-12, abs=1e-300)
        assert v.unit == model.unit(n)
        assert by_name[f"der({n})"].derivative is v
    p_cmd = by_name["regulator.p_cmd"]
    assert (p_cmd.causality, float(p_cmd.min), float(p_cmd.max)) == ("input", 0.0, 6e5)
    load = by_name["load.m"]
    assert (load.causality, load.variability) == ("parameter", "tunable")
    thread = by_name["myofibril.actin0.l"]  # the start positions depend on it
    assert (thread.variability, thread.initial) == ("fixed", "exact")
    assert float(load.start) == pytest.approx(0.051, rel=1e-15)
    assert by_name["myofibril.length"].causality == "output"
    assert float(by_name["myofibril.aps1.chamber.p"].min) == 0.0
    units = {u.name: u for u in md.unitDefinitions}
    assert (units["Pa"].baseUnit.kg, units["Pa"].baseUnit.m, units["Pa"].baseUnit.s) == (1, -1, -2)
    assert md.defaultExperiment.stopTime == "2.0"


def test_length_depends_on_states_not_input(step_fmu):
    md = read_model_description(step_fmu)
    (length,) = [u for u in md.outputs if u.variable.name == "myofibril.length"]
    assert {v.name for v in length.dependencies} == {"load.s"}
    (reg,) = [u for u in md.derivatives if u.variable.name == "der(regulator.p_set)"]
    assert {v.name for v in reg.dependencies} == {"regulator.p_set", "regulator.p_cmd"}


def test_archive_holds_binary_and_sources(step_fmu):
    names = zipfile.ZipFile(step_fmu).namelist()
    assert "binaries/linux64/hanging_n3_full.so" in names
    md = read_model_description(step_fmu)
    assert {f"sources/{f}" for f in md.buildConfigurations[0].sourceFileSets[0].sourceFiles} <= set(
        names
    )
    assert "sources/fmi2.c" in names and "sources/sm_casadi.c" in names
    assert {"sources/physics.h", "sources/instance.h", "sources/model_data.h"} <= set(names)


@pytest.mark.parametrize(
    ("unit", "attrs"),
    [
        ("Pa", {"kg": "1", "m": "-1", "s": "-2"}),
        ("J/(kg*K)", {"m": "2", "s": "-2", "K": "-1"}),
        ("m^3/(s*Pa)", {"m": "4", "s": "1", "kg": "-1"}),
        ("rad", {"rad": "1"}),
        ("1", {}),
    ],
)
def test_base_units(unit, attrs):
    assert base_units(unit) == attrs


def test_export_refuses_bad_arguments(tmp_path):
    model = hanging_load(1)
    with pytest.raises(ParameterError, match="fmi_version"):
        export_fmu(model, tmp_path / "a.fmu", fmi_version=4)
    with pytest.raises(ParameterError, match=".fmu"):
        export_fmu(model, tmp_path / "a.zip")
    with pytest.raises(ParameterError, match="existing folder"):
        export_fmu(model, tmp_path / "missing" / "a.fmu")
    with pytest.raises(ParameterError, match="nz = 0"):
        export_fmu(hanging_load(1, fidelity="static_chain"), tmp_path / "a.fmu")
    with pytest.raises(ParameterError, match="600000"):
        export_fmu(model, tmp_path / "a.fmu", inputs={"regulator.p_cmd": -1.0})
    with pytest.raises(ParameterError, match="'model' = 'step-50g'.*a flattened Model"):
        export_fmu("step-50g", tmp_path / "a.fmu")  # the CLI builds a scene's model first
    assert not list(tmp_path.iterdir())


def test_cli_refuses_a_scene_without_one_model_level(tmp_path, capsys):
    out = tmp_path / "x.fmu"
    assert main(["export-fmu", "paper-isometric", "--out", str(out)]) == 2
    assert "transient" in capsys.readouterr().err
    assert main(["export-fmu", "step-50g-auto", "--out", str(out)]) == 2
    assert "exported at one level" in capsys.readouterr().err
    assert not out.exists()


def test_cli_replaces_only_an_fmu_unless_forced(tmp_path, capsys, iso_scene):
    """``--out`` an existing file that is not an FMU is refused (the file untouched) unless
    ``--force``; an existing FMU is replaced; a folder is refused; a missing parent folder
    is created, as ``run`` creates its results folder."""
    notes = tmp_path / "notes.fmu"
    notes.write_text("my notes")
    assert main(["export-fmu", str(iso_scene), "--out", str(notes)]) == 2
    assert "the file exists and is not an FMU; --force replaces it" in capsys.readouterr().err
    assert notes.read_text() == "my notes"
    (tmp_path / "folder.fmu").mkdir()
    assert main(["export-fmu", str(iso_scene), "--out", str(tmp_path / "folder.fmu")]) == 2
    assert "it is a folder" in capsys.readouterr().err
    assert main(["export-fmu", str(iso_scene), "--out", str(tmp_path / "a.zip")]) == 2
    assert "a file name ending in .fmu" in capsys.readouterr().err
    nested = tmp_path / "new" / "folder" / "iso.fmu"
    assert main(["export-fmu", str(iso_scene), "--out", str(nested)]) == 0
    assert zipfile.is_zipfile(nested)
    assert main(["export-fmu", str(iso_scene), "--out", str(nested), "--fmi", "3"]) == 0
    assert "3.0" in read_model_description(nested).fmiVersion  # the FMU was replaced
    assert main(["export-fmu", str(iso_scene), "--out", str(notes), "--force"]) == 0
    assert zipfile.is_zipfile(notes)


def test_a_failing_compiler_is_an_error_and_writes_nothing(tmp_path, monkeypatch):
    model = hanging_load(1)
    monkeypatch.setenv("CC", "false")  # a "compiler" that always fails
    with pytest.raises(FmuError, match="the C compiler failed"):
        export_fmu(model, tmp_path / "a.fmu")
    monkeypatch.setenv("CC", "no-such-compiler-here")
    with pytest.raises(FmuError, match="no C compiler"):
        export_fmu(model, tmp_path / "a.fmu")
    assert not list(tmp_path.iterdir())


def test_the_fmu_package_never_imports_scenarios():
    """Data flows one way: the scenarios layer builds a scene's model and calls the FMU
    package, never the reverse (export_fmu took a scenario and imported it before)."""
    import ast
    from pathlib import Path

    import sarcomere.fmu

    for source in Path(sarcomere.fmu.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(source.read_text())):
            if isinstance(node, ast.ImportFrom):
                names = [("." * node.level) + (node.module or "")]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                assert "scenarios" not in name, f"{source.name} imports {name}"
