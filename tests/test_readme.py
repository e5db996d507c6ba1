"""The README's Python examples run as written (a new user copies them first)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_examples_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert len(blocks) >= 2
    namespace: dict = {}
    for block in blocks:  # later blocks build on the names of earlier ones
        exec(compile(block, str(README), "exec"), namespace)  # noqa: S102
    sim, rest = namespace["sim"], namespace["rest"]
    assert abs(sim.t - 1.0) < 1e-12
    # the bang-bang loop holds the length near its 176 mm switching point
    assert abs(sim.signal("myofibril.length") - 0.176) < 2e-3
    assert rest.signals["myofibril.length"] > 0.176
