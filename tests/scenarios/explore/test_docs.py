"""docs/studies.md's Python examples run as the scripts they are (issue 24, bug 14: without
``if __name__ == "__main__":`` a script failed with "Nanny failed to start")."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

DOC = Path(__file__).parents[3] / "docs" / "studies.md"
BLOCKS = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}


def test_every_example_is_a_script_with_the_main_guard():
    assert len(BLOCKS) == 3
    for block in BLOCKS:
        assert 'if __name__ == "__main__":' in block, block


@pytest.mark.slow  # the packaged montecarlo-family and sensitivity-step, on 2 workers
@pytest.mark.parametrize("block", BLOCKS[:2], ids=["montecarlo", "sensitivity"])
def test_the_examples_run_as_scripts(block, tmp_path):
    script = tmp_path / "example.py"
    script.write_text(block + "    print(repr(ds.status.size))\n")
    done = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=ENV, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert int(done.stdout.split()[-1]) > 0


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_a_script_without_the_guard_is_told_why(tmp_path):
    script = tmp_path / "unguarded.py"
    script.write_text(
        f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import test_engine as t\n"
        f"t.run(t.StandIn(), {str(tmp_path / 'out')!r}, workers=1)\n"
    )
    done = subprocess.run(
        [sys.executable, str(script)], env=ENV, capture_output=True, text=True, timeout=300
    )
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert "ClusterError: the embedded Dask cluster's workers did not start" in last
    assert 'under if __name__ == "__main__":' in last
