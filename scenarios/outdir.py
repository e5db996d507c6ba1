"""Results folders that hold all of one run or stay untouched.

:func:`check_out_dir` refuses a bad destination before anything is computed;
:func:`staged` gives the run a temporary sibling folder and swaps it in for the
destination only when the run succeeded, so a folder never mixes two runs' files and a
failed or interrupted run (an exception, Ctrl-C, SIGTERM through the CLI) leaves nothing
behind.

Rules (docs/scenarios.md, "Results folders"): an existing folder is replaced only when it
holds a previous run's own marker (``summary.json`` naming its scenario, or
``calibration.json``) and nothing that run did not write; a symbolic link is followed,
the results go into its target and the link stays; the folder gets the permissions the
umask gives a new folder (``mkdir`` would), not a temporary folder's 0700.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sarcomere.dynamics.errors import ParameterError

#: What a results folder may be, for error messages.
ALLOWED = (
    "a new folder, an empty folder, or a folder a previous run wrote (its summary.json "
    "and the files that summary lists)"
)

#: A file that marks a folder as written by a previous run (and so replaceable) -> a key
#: every such file of ours holds.
MARKERS = {"summary.json": "scenario", "calibration.json": "fitted"}

#: Files ``sarcomere calibrate`` writes beside calibration.json (which lists none).
CALIBRATION_FILES = ("family.json", "family.csv", "concentric-family.png")


def _marker(folder: Path) -> tuple[str, set[str]] | None:
    """``(marker name, names its run wrote)`` when ``folder`` holds a readable marker of
    one of our runs (a JSON object with the marker's key), else None."""
    for name, key in MARKERS.items():
        try:
            record = json.loads((folder / name).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError):
            continue
        if not isinstance(record, dict) or not record.get(key):
            continue
        listed = record.get("files", CALIBRATION_FILES if name == "calibration.json" else [])
        if not isinstance(listed, list) or not all(isinstance(f, str) for f in listed):
            continue
        return name, {name, *listed}
    return None


def _check_replaceable(folder: Path, name: str, out: str) -> None:
    """Refuse a non-empty ``folder`` that is not wholly a previous run's."""
    present = sorted(p.name for p in folder.iterdir())
    if not present:
        return
    found = _marker(folder)
    if found is None:
        kinds = [m for m in MARKERS if (folder / m).exists()]
        why = (
            f"its {kinds[0]} is not a sarcomere run's (a JSON object with '{MARKERS[kinds[0]]}')"
            if kinds
            else "a folder holding files no run wrote (no summary.json)"
        )
        raise ParameterError(name, out, ALLOWED, why)
    marker, written = found
    foreign = [f for f in present if f not in written]
    if foreign:
        shown = ", ".join(foreign[:5]) + (
            f" and {len(foreign) - 5} more" if len(foreign) > 5 else ""
        )
        raise ParameterError(
            name,
            out,
            ALLOWED,
            f"a folder holding files no run wrote: {shown} (not listed in its {marker}); "
            "they would be deleted with the old results",
        )


def _followed(path: Path, name: str, out: str) -> Path:
    """``path``, or the target of the symbolic link ``path`` is (which may not exist yet)."""
    if not path.is_symlink():
        return path
    try:
        return Path(os.path.realpath(path, strict=True))
    except (FileNotFoundError, NotADirectoryError):  # dangling: the checks judge its target
        return Path(os.path.realpath(path))
    except OSError as exc:
        raise ParameterError(name, out, ALLOWED, f"a link that cannot be followed: {exc}") from None


def _umask() -> int:
    """The process's file-creation mask."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


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
        ``out`` as a path; for a symbolic link (even a dangling one), its target.

    Raises
    ------
    ParameterError
        ``out`` is empty, an existing file, under a file, the current folder or one of its
        parents, a folder holding files no run wrote (or a ``summary.json`` that is not a
        run's), a link loop, or not writable.
    """
    if str(out).strip() == "":
        raise ParameterError(name, str(out), ALLOWED, "empty path")
    path = _followed(Path(out), name, str(out))
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
        _check_replaceable(full, name, str(out))
    return path


@contextmanager
def staged(out: Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``out``; on success it replaces ``out`` whole.

    On an exception (KeyboardInterrupt included) the temporary folder and any parent
    folders created for it are removed, and ``out`` is left as it was. The folder put in
    place has the umask's permissions of a new folder.
    """
    out = Path(out)
    created = [p for p in reversed(out.absolute().parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        yield tmp
        tmp.chmod(0o777 & ~_umask())  # mkdtemp made it 0700
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
