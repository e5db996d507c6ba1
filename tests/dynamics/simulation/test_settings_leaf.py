"""``simulation/settings.py`` is the leaf the method modules share: it imports no other
module of the simulation package, not even for annotations (no type-level cycle with
``common.py``), and the Model only for annotations."""

import ast
from pathlib import Path

import sarcomere.dynamics.simulation.settings as settings


def test_settings_imports_no_simulation_module_and_the_model_only_for_types():
    tree = ast.parse(Path(settings.__file__).read_text(encoding="utf-8"))
    type_only = {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
        for n in ast.walk(block)
    }
    imports = [n for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert imports and all(not (n.level == 1) for n in imports)  # nothing from ``.x``
    runtime = {n.module for n in imports if id(n) not in type_only}
    assert "modeling.model" not in runtime
    assert {n.module for n in imports if id(n) in type_only} == {"modeling.model"}
