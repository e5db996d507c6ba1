"""Every Python block of README.md and docs/*.md is executed by some test, so an example
that drifts from the API fails CI (issue 28). The pages with their own test (which also
checks what the blocks produced) are listed in COVERED; every other page, a new one
included, has its blocks run here, in order, in one namespace, in a fresh folder."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)

#: Page -> the test that runs its Python blocks (and checks their results).
COVERED = {
    "README.md": "tests/test_readme.py",
    "docs/model.md": "tests/test_readme.py",
    "docs/scenarios.md": "tests/test_readme.py",
    "docs/controllers.md": "tests/controllers/test_docs.py",
    "docs/fmu.md": "tests/fmu/test_docs.py",
    "docs/cosim.md": "tests/fmu/test_docs.py",
    "docs/studies.md": "tests/scenarios/explore/test_docs.py",
}
#: Blocks that cannot run here, by a text they contain, with the reason.
NOT_RUN = {"SLURMCluster": "needs a Slurm cluster and dask-jobqueue (its guard is tested)"}


def pages_with_blocks() -> list[str]:
    pages = ["README.md", *(f"docs/{p.name}" for p in sorted((ROOT / "docs").glob("*.md")))]
    return [p for p in pages if BLOCK.search((ROOT / p).read_text(encoding="utf-8"))]


def test_every_page_with_python_blocks_is_executed_by_a_test():
    pages = pages_with_blocks()
    assert {"README.md", "docs/paper.md", "docs/fmu.md"} <= set(pages)
    for page, test in COVERED.items():
        assert page in pages, f"{page} has no Python block: drop it from COVERED"
        text = (ROOT / test).read_text(encoding="utf-8")
        assert Path(page).name in text, f"{test} does not read {page}"


def test_only_the_slurm_block_is_left_out():
    left_out = [
        (page, block)
        for page in pages_with_blocks()
        for block in BLOCK.findall((ROOT / page).read_text(encoding="utf-8"))
        if any(key in block for key in NOT_RUN)
    ]
    assert [page for page, _ in left_out] == ["docs/studies.md"]
    assert 'if __name__ == "__main__":' in left_out[0][1]


@pytest.mark.slow  # the blocks build models and run them
@pytest.mark.parametrize("page", [p for p in pages_with_blocks() if p not in COVERED])
def test_the_python_blocks_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write, write here
    namespace: dict = {"__name__": "__main__"}
    blocks = BLOCK.findall((ROOT / page).read_text(encoding="utf-8"))
    for block in blocks:  # later blocks build on the names of earlier ones
        exec(compile(block, page, "exec"), namespace)  # noqa: S102
    assert blocks
