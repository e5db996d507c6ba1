"""The Python blocks of docs/fmu.md and docs/cosim.md run as written, in order, in a fresh
folder (a new user pastes them; they export FMUs, so gcc runs)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _run(page: str) -> dict:
    blocks = re.findall(r"```python\n(.*?)```", (DOCS / page).read_text(), re.S)
    assert len(blocks) >= 2
    namespace: dict = {"__name__": "__main__"}
    for block in blocks:  # later blocks build on the names and files of earlier ones
        exec(compile(block, f"docs/{page}", "exec"), namespace)  # noqa: S102
    return namespace


def test_docs_fmu_python_blocks_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ns = _run("fmu.md")
    for name in ("step-50g.fmu", "h3.fmu", "pid.fmu", "nmpc.fmu"):
        assert (tmp_path / name).is_file(), name
    cs, me = ns["cs"], ns["me"]
    assert cs["time"][-1] == pytest.approx(2.0)
    shortened = cs["myofibril.length"][0] - cs["myofibril.length"][-1]
    assert shortened > 1e-3  # the 0.1 MPa step contracts the muscle [m]
    np.testing.assert_allclose(me["myofibril.length"][-1], cs["myofibril.length"][-1], rtol=1e-4)


def test_docs_cosim_python_blocks_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ns = _run("cosim.md")
    result = ns["result"]
    muscle, twin = result["muscle.myofibril.length"], result["twin.myofibril.length"]
    assert muscle[0] - muscle[-1] > 1e-3  # it contracted [m]
    assert np.max(np.abs(twin - muscle)) > 0  # the twin follows the muscle's p_out, late
    A, B = ns["A"], ns["B"]
    assert A.shape == (len(ns["joint"].state_names),) * 2 and B.shape[1] == 1
