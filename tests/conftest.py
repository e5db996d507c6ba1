"""Tests write only under tmp_path: the checkout is left as it was found (checked for the
whole session)."""

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _status() -> str:
    done = subprocess.run(
        ["git", "status", "--porcelain", "--ignored", "--untracked-files=all"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    lines = done.stdout.splitlines()
    noise = ("__pycache__", ".pytest_cache", ".ruff_cache", ".venv", ".egg-info", ".pyc")
    return "\n".join(ln for ln in lines if not any(n in ln for n in noise))


@pytest.fixture(scope="session", autouse=True)
def checkout_untouched():
    """Fail the session if the tests left files in (or removed files from) the checkout."""
    before = _status()
    yield
    after = _status()
    assert after == before, f"the tests changed the checkout:\n{after}"


@pytest.fixture(scope="session", autouse=True)
def compile_cache(tmp_path_factory):
    """Compiled libraries (``radau``) go to a session folder, never the user's cache."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SARCOMERE_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    yield
    mp.undo()
