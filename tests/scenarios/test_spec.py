"""The scene schema stays light: parsing a scene loads no CasADi, and ``scenarios/spec``
imports nothing back from the modules that read scenes (no cycle, not even for types)."""

import ast
import json
import subprocess
import sys
from pathlib import Path

from sarcomere.dynamics import schema
from sarcomere.dynamics.components.chains import CHAIN_LEVELS, INSTANT_LEVELS
from sarcomere.scenarios import spec

PROBE = """
import json, sys
from sarcomere.scenarios.catalog import packaged_scenarios
from sarcomere.scenarios.loader import load_scenario
for path in packaged_scenarios().values():
    load_scenario(path)
print(json.dumps([m for m in ("casadi", "sarcomere.dynamics.assemblies") if m in sys.modules]))
"""


def test_parsing_every_packaged_scene_loads_no_casadi():
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == []


def test_the_schema_names_the_levels_the_assemblies_build():
    assert schema.FIDELITIES == (*CHAIN_LEVELS, "grouped", "symmetric", *INSTANT_LEVELS)


def test_spec_imports_no_scenario_module_even_for_types():
    tree = ast.parse(Path(spec.__file__).read_text(encoding="utf-8"))
    relative = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level]
    assert relative == []
