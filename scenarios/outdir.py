"""Results folders that hold all of one run or stay untouched.

:func:`check_out_dir` refuses a bad destination before anything is computed;
:func:`staged` gives the run a temporary sibling folder and swaps it in for the
destination only when the run succeeded, so a folder never mixes two runs' files and a
failed run leaves nothing behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sarcomere.dynamics.errors import ParameterError

#: What a results folder may be, for error messages.
ALLOWED = "a new folder, an empty folder, or a folder a previous run wrote (with summary.json)"

#: A file that marks a folder as written by a previous run (and so replaceable).
MARKERS = ("summary.json", "calibration.json")


def check_out_dir(out: str | Path, name: str = "out_dir") -> Path:
    """Refuse a destination that cannot or must not become a results folder.

    Parameters
    ----------
    out : str or pathlib.Path
        The folder to write.
    name : str
        How the caller names the setting in messages (``"--out"``).

    Returns
    -------
    pathlib.Path
        ``out`` as a path.

    Raises
    ------
    ParameterError
        ``out`` is empty, an existing file, under a file, the current folder or one of its
        parents, a folder holding files of something other than a run, or not writable.
    """
    if str(out).strip() == "":
        raise ParameterError(name, str(out), ALLOWED, "empty path")
    path = Path(out)
    full = path.resolve()
    if full == Path.cwd().resolve() or full in Path.cwd().resolve().parents:
        raise ParameterError(name, str(out), ALLOWED, "would replace the current folder")
    if path.exists() and not path.is_dir():
        raise ParameterError(name, str(out), ALLOWED, "an existing file")
    existing = next(p for p in (full, *full.parents) if p.exists())
    if not existing.is_dir():
        raise ParameterError(name, str(out), ALLOWED, f"'{existing}' is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ParameterError(name, str(out), ALLOWED, f"'{existing}' is not writable")
    if existing == full:
        if not os.access(full.parent, os.W_OK | os.X_OK):
            raise ParameterError(name, str(out), ALLOWED, f"'{full.parent}' is not writable")
        if any(full.iterdir()) and not any((full / m).is_file() for m in MARKERS):
            raise ParameterError(
                name, str(out), ALLOWED, "a folder holding files no run wrote (no summary.json)"
            )
    return path


@contextmanager
def staged(out: Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``out``; on success it replaces ``out`` whole.

    On an exception the temporary folder and any parent folders created for it are
    removed, and ``out`` is left as it was.
    """
    out = Path(out)
    created = [p for p in reversed(out.absolute().parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        yield tmp
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.rename(out, old / out.name)
        try:
            os.rename(tmp, out)
        except OSError:
            if old is not None:
                os.rename(old / out.name, out)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for parent in reversed(created):
            try:
                parent.rmdir()
            except OSError:
                break
        raise
