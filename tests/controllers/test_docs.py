"""docs/controllers.md's Python blocks run as pasted, one after the other in one script
(issue 24: the second used ``model`` where the first had made ``m``)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "controllers.md"


@pytest.mark.slow  # builds an NMPC: the full suite (CI) runs it
def test_controllers_doc_python_blocks_run_as_a_script(tmp_path):
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    assert len(blocks) >= 3
    script = tmp_path / "controllers_doc.py"
    script.write_text("\n".join(blocks), encoding="utf-8")
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-2000:]
