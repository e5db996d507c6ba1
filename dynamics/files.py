"""Reading the text files a user names (scenarios, input tables) with errors that say what
the path is when it is not a regular text file.

A directory, a FIFO or a device is reported as such instead of "no such file", and is never
opened (reading a FIFO would block until a writer comes); binary bytes are reported with
their position instead of a ``UnicodeDecodeError``.
"""

from __future__ import annotations

import stat
from pathlib import Path

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def path_kind(path: Path) -> str | None:
    """What ``path`` is if not a regular file ("a directory", "a FIFO (named pipe)", "a
    character device", "a broken symbolic link", "missing", ...); None for a regular file
    (or a link to one)."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return "a broken symbolic link" if path.is_symlink() else "missing"
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    if stat.S_ISREG(mode):
        return None
    return next((text for test, text in _KINDS if test(mode)), "not a regular file")


def read_text(path: Path) -> str:
    """The UTF-8 text of the regular file ``path``.

    Raises
    ------
    ValueError
        ``path`` is not a regular file (saying what it is), cannot be read, or holds bytes
        that are not UTF-8 text (their position; a binary file?).
    """
    kind = path_kind(path)
    if kind is not None:
        raise ValueError(f"is {kind}, not a file" if kind != "missing" else "no such file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read: {exc.strerror}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ValueError(
            f"not UTF-8 text: byte 0x{data[exc.start]:02x} at offset {exc.start} (line "
            f"{line}); a binary file? expected a text file"
        ) from None
