"""A progress line on stderr for runs that take a while.

:func:`progress` prints ``label: 12 s`` on one rewritten line once a run has taken longer
than ``delay`` seconds, and clears it at the end. It stays silent when disabled
(``--quiet``) and when the stream is not a terminal (logs and pipes stay clean).
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

    def tick() -> None:
        if done.wait(delay):
            return
        while True:
            out.write(f"\r{label}: {time.perf_counter() - start:.0f} s")
            out.flush()
            shown.append(True)
            if done.wait(every):
                return

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()
        if shown:
            out.write(f"\r{label}: done in {time.perf_counter() - start:.1f} s\n")
            out.flush()
