"""A progress line on stderr for runs that take a while.

:func:`progress` prints ``label: 12 s`` on one rewritten line once a run has taken longer
than ``delay`` seconds, and at the end replaces it with ``label: done in 12.3 s`` (or
clears it when the block failed, so an error message stands alone). It stays silent when
disabled (``--quiet``) and when the stream is not a terminal (logs and pipes stay clean). Code
running inside the block adds its own state to the line with :func:`report` (a
co-simulation its simulated time: ``running x: 12 s, t = 1.2 / 3 s``).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO

#: Seconds before the progress line appears.
DELAY_S = 2.0

_status: list[str] = []
"""The state shown on the active progress line (empty: none active or nothing reported)."""


def report(text: str) -> None:
    """Show ``text`` after the elapsed time on the active progress line; nothing when no
    line is active (quiet runs, pipes)."""
    if _status:
        _status[-1] = text


@contextmanager
def progress(
    label: str,
    *,
    enabled: bool = True,
    stream: TextIO | None = None,
    delay: float | None = None,
    every: float = 1.0,
) -> Iterator[None]:
    """Show ``label`` and the elapsed time on ``stream`` (stderr) while the block runs,
    from ``delay`` (default :data:`DELAY_S`) seconds on, every ``every`` seconds."""
    out = sys.stderr if stream is None else stream
    delay = DELAY_S if delay is None else delay
    if not enabled or not out.isatty():
        yield
        return
    done = threading.Event()
    start = time.perf_counter()
    shown = []
    _status.append("")
    width = [0]

    def tick() -> None:
        if done.wait(delay):
            return
        while True:
            state = f", {_status[-1]}" if _status[-1] else ""
            line = f"{label}: {time.perf_counter() - start:.0f} s{state}"
            out.write(f"\r{line:<{width[0]}}")
            width[0] = max(width[0], len(line))
            out.flush()
            shown.append(True)
            if done.wait(every):
                return

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    ok = False
    try:
        yield
        ok = True
    finally:
        done.set()
        thread.join()
        _status.pop()
        if shown:  # a failed or interrupted run: the line is cleared, its error follows
            line = f"{label}: done in {time.perf_counter() - start:.1f} s\n" if ok else ""
            out.write(f"\r{' ' * width[0]}\r{line}")
            out.flush()
