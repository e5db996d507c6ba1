"""The CLI limits the BLAS/LAPACK thread pools (SARCOMERE_BLAS_THREADS, default 1)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from sarcomere.dynamics.errors import ParameterError
from sarcomere.scenarios import cli
from sarcomere.scenarios.threads import ENV, POOL_VARIABLES, blas_threads, limited_blas


def _blas_threads() -> set[int]:
    return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}


def test_commands_run_with_the_asked_number_of_blas_threads(monkeypatch, capsys):
    np.linalg.solve(np.eye(3), np.ones(3))  # BLAS loaded
    seen = []

    def handler(args):
        seen.append(_blas_threads())
        return 0

    original = cli.build_parser
    probe = [cli.Command("probe", "-", handler)]
    monkeypatch.setattr(cli, "build_parser", lambda argv=None: original(probe, argv))
    monkeypatch.delenv(ENV, raising=False)
    assert cli.main(["probe"]) == 0
    monkeypatch.setenv(ENV, "2")
    assert cli.main(["probe"]) == 0
    assert seen == [{1}, {2}]
    monkeypatch.setenv(ENV, "0")
    assert cli.main(["probe"]) == 2
    assert f"error: parameter '{ENV}' = '0'" in capsys.readouterr().err


@pytest.mark.parametrize("raw", ["0", "-1", "two", ""])
def test_a_bad_thread_count_is_refused_by_name(monkeypatch, raw):
    monkeypatch.setenv(ENV, raw)
    with pytest.raises(ParameterError, match=ENV):
        blas_threads()
    with pytest.raises(ParameterError, match=ENV):
        limited_blas()


def test_libraries_loaded_by_the_command_are_limited_too():
    """The CLI imports numpy and scipy only when a command runs, after the limit is set:
    threadpoolctl alone left their pools at the core count."""
    code = (
        "import json, os, sys\n"
        "from sarcomere.scenarios import cli\n"
        "def probe(args):\n"
        "    import numpy, scipy.linalg\n"
        "    from threadpoolctl import threadpool_info\n"
        "    print(json.dumps(sorted({p['num_threads'] for p in threadpool_info()})))\n"
        "    return 0\n"
        "original = cli.build_parser\n"
        "cli.build_parser = lambda argv=None: original([cli.Command('probe', '-', probe)], argv)\n"
        "assert 'numpy' not in sys.modules\n"
        "sys.exit(cli.main(['probe']))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in POOL_VARIABLES and k != ENV}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert json.loads(done.stdout) == [1], done.stderr
