"""The public scene binding: every path that simulates a bound scene (the transient kind
at a level and at "auto", co-simulation's native run, the study evaluator) goes through
``binding.run``; nothing else in the scenarios imports a private name of it."""

import ast
import textwrap
from pathlib import Path

import pytest

from sarcomere.scenarios import binding, parse_scenario, run
from sarcomere.scenarios.catalog import packaged_scenarios
from sarcomere.scenarios.explore import spec
from sarcomere.scenarios.explore.evaluate import evaluate_batch

SCENARIOS = Path(binding.__file__).parent


@pytest.fixture
def runs(monkeypatch):
    """The models ``binding.run`` simulated, by name (it still runs them)."""
    seen = []
    real = binding.run

    def spy(model, *args, **kwargs):
        seen.append(model.name)
        return real(model, *args, **kwargs)

    monkeypatch.setattr(binding, "run", spy)
    return seen


def _short(name: str, stop: str = "0.5 s") -> str:
    text = packaged_scenarios()[name].read_text(encoding="utf-8")
    return text.replace('stop_time = "2 s"', f'stop_time = "{stop}"')


@pytest.mark.parametrize("name", ["step-50g", "step-50g-auto"])
def test_the_transient_kind_runs_through_the_binding(tmp_path, runs, name):
    out = run(parse_scenario(_short(name), f"{name}.toml"), tmp_path, quiet=True)
    assert out.fidelity == "full" and len(runs) == 1


def test_the_study_evaluator_runs_through_the_binding(runs):
    study = spec.parse_study(
        textwrap.dedent(
            """
            [study]
            kind = "grid"
            base = "step-50g"
            [study.grid]
            load = ["20 g", "30 g"]
            """
        ),
        "/nonexistent/s.toml",
    )
    got = evaluate_batch(study, [0, 1])
    assert got.status.tolist() == [0, 0] and len(runs) == 2


@pytest.mark.slow  # exports and compiles an FMU: the full suite (CI) runs it
def test_cosimulation_native_run_goes_through_the_binding(tmp_path, runs):
    text = packaged_scenarios()["cosim-roundtrip"].read_text(encoding="utf-8")
    run(parse_scenario(text, "cosim.toml"), tmp_path, quiet=True)
    assert len(runs) == 1


def test_no_module_imports_a_private_name_of_the_binding():
    for path in SCENARIOS.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("binding"):
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{path.name} imports {private} from the binding"
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
                if node.value.id in ("binding", "scene_binding") and node.attr.startswith("_"):
                    pytest.fail(f"{path.name} uses binding.{node.attr}")
