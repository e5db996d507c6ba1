"""The Python examples of the README and of the docs pages below run as written (a new user
copies them first): each page's blocks in order, in one namespace, in a fresh folder."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = ["README.md", "docs/model.md", "docs/architecture.md", "docs/scenarios.md"]
"""The pages whose examples this file runs (the other docs pages have their own tests)."""


def run_blocks(page: Path) -> dict:
    """Run the ```python blocks of ``page`` in order; returns their namespace."""
    namespace: dict = {"__name__": "__main__"}
    for block in re.findall(r"```python\n(.*?)```", page.read_text(), re.S):
        exec(compile(block, str(page), "exec"), namespace)  # noqa: S102
    return namespace


def test_readme_python_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = run_blocks(README)
    sim, rest = namespace["sim"], namespace["rest"]
    assert abs(sim.t - 1.0) < 1e-12
    # the bang-bang loop holds the length near its 176 mm switching point
    assert abs(sim.signal("myofibril.length") - 0.176) < 2e-3
    assert rest.signals["myofibril.length"] > 0.176


DOCS = [p for p in PAGES[1:] if "```python" in (ROOT / p).read_text()]


def test_the_docs_pages_have_examples():
    assert len(re.findall("```python", README.read_text())) >= 2
    assert {"docs/model.md", "docs/scenarios.md"} <= set(DOCS)


@pytest.mark.parametrize("page", DOCS)
def test_docs_python_examples_run(page, tmp_path, monkeypatch):
    from sarcomere.scenarios import runner

    monkeypatch.chdir(tmp_path)  # examples that write, write here
    before = set(runner._RUNNERS) | set(runner.BUILTIN_KINDS)
    try:
        run_blocks(ROOT / page)
    finally:  # a kind an example registers is not left to the other tests
        for kind in set(runner._RUNNERS) - before:
            del runner._RUNNERS[kind]
    written = re.findall(r'"(out/[\w-]+)"', (ROOT / page).read_text())
    assert all((tmp_path / folder / "summary.json").is_file() for folder in written)
