"""The compiled-library cache (dynamics/simulation/compiled.py) under several processes
building the same library at once into a fresh cache folder, as Dask workers do."""

import ctypes
import multiprocessing
import os
import time
from pathlib import Path

import pytest

SOURCE = "int sm_answer(void) { return 42; }\n"


def _build(folder: str, barrier, slow: float) -> tuple[str, bool, int]:
    """Wait for the others, then build (the compile held open ``slow`` seconds) and
    call the library."""
    os.environ["SARCOMERE_CACHE_DIR"] = folder
    from sarcomere.dynamics.simulation import compiled

    def units(tmp: Path):
        time.sleep(slow)  # every process is inside the compile at once
        src = tmp / "answer.c"
        src.write_text(SOURCE)
        return [compiled.Unit(src, ("-O0",))]

    barrier.wait()
    path, built = compiled.shared_library("answer", [SOURCE], units)
    lib = ctypes.CDLL(str(path))
    return str(path), built, lib.sm_answer()


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_processes_compiling_the_same_library_at_once(tmp_path):
    ctx = multiprocessing.get_context("spawn")
    k = 3
    with ctx.Manager() as manager:
        barrier = manager.Barrier(k)
        with ctx.Pool(k) as pool:
            jobs = [pool.apply_async(_build, (str(tmp_path), barrier, 0.5)) for _ in range(k)]
            results = [j.get(timeout=60) for j in jobs]
    paths = {p for p, _, _ in results}
    assert len(paths) == 1 and all(answer == 42 for _, _, answer in results)
    assert sum(built for _, built, _ in results) >= 2  # they did compile concurrently
    files = sorted(p.name for p in (tmp_path / "lib").iterdir())
    assert files == [Path(paths.pop()).name]  # one library, no partial files left
    # a later process finds it and does not compile
    with ctx.Pool(1) as pool:
        path, built, answer = pool.apply(_build_again, (str(tmp_path),))
    assert not built and answer == 42


def _build_again(folder: str):
    os.environ["SARCOMERE_CACHE_DIR"] = folder
    from sarcomere.dynamics.simulation import compiled

    def units(tmp: Path):
        raise AssertionError("compiled again")

    path, built = compiled.shared_library("answer", [SOURCE], units)
    return str(path), built, ctypes.CDLL(str(path)).sm_answer()
