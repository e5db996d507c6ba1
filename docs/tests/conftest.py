"""The docs tests run after a build: ``sphinx-build -W --keep-going -n docs docs/_build/html``
(``.ci/run`` builds first). ``SARCOMERE_DOCS_HTML`` points them at another build folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def html() -> Path:
    folder = Path(os.environ.get("SARCOMERE_DOCS_HTML", DOCS / "_build" / "html"))
    if not (folder / "objects.inv").is_file():
        pytest.fail(f"no built site in {folder}: run sphinx-build -W -n docs {folder} first")
    return folder
