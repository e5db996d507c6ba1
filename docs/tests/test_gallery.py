"""The gallery was executed: every ``examples/plot_*.py`` has its page with the figures it
drew (a fast build, ``-D plot_gallery=0``, runs no example: from a clean tree its pages
have no figure and fail here; after a full build it reuses that build's pages)."""

from __future__ import annotations

import re
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_every_example_ran_and_drew(html):
    scripts = sorted(EXAMPLES.glob("plot_*.py"))
    assert len(scripts) >= 12
    for script in scripts:
        page = html / "gallery" / f"{script.stem}.html"
        assert page.is_file(), page
        text = page.read_text(encoding="utf-8")
        figures = re.findall(r'<img [^>]*src="[^"]*sphx_glr_' + script.stem + r"_\d+\.png", text)
        assert figures, f"{script.name}: no figure on its page (not executed?)"
