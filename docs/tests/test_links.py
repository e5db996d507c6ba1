"""No broken internal link, image or anchor anywhere in the built site (the local files
are read, nothing is fetched): every relative ``href``/``src`` names a file of the build,
and every ``#fragment`` an id of its page."""

from __future__ import annotations

from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[tuple[str, str]] = []  # (tag.attribute, target)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        for key in ("id", "name"):
            if attrs.get(key):
                self.ids.add(attrs[key])
        for key in ("href", "src"):
            if attrs.get(key) and tag in ("a", "img", "link", "script", "source"):
                self.links.append((f"{tag}.{key}", attrs[key]))


def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8", errors="replace"))
    return page


def broken_links(html: Path) -> list[str]:
    pages = {p: _parse(p) for p in html.rglob("*.html") if "_static" not in p.parts}
    broken = []
    for path, page in pages.items():  # _static holds the theme's templates, not pages
        for where, target in page.links:
            url = urlsplit(target)
            if url.scheme or url.netloc or target.startswith(("mailto:", "javascript:")):
                continue  # external: not checked offline
            file = (path.parent / unquote(url.path)).resolve() if url.path else path
            if file.is_dir():
                file = file / "index.html"
            name = f"{path.relative_to(html)}: {where}={target}"
            if not file.is_file():
                broken.append(f"{name} (no file)")
            elif url.fragment and file.suffix == ".html":
                ids = pages[file].ids if file in pages else _parse(file).ids
                if unquote(url.fragment) not in ids:
                    broken.append(f"{name} (no anchor)")
    return broken


def test_no_broken_internal_link_image_or_anchor(html):
    assert len(list(html.rglob("*.html"))) > 50
    broken = broken_links(html)
    assert not broken, "\n".join(broken[:50])
