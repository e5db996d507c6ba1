"""The compiled integrators' C sources: the headers ``radau.c`` and ``rodas.c`` include
(directly or through another header) are the listed ``radau.HEADERS``, and each is in the
compile caches' keys of both (an edited header makes new libraries)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from sarcomere.dynamics.modeling.component import Component, System
from sarcomere.dynamics.simulation import compiled, radau, rosenbrock
from sarcomere.dynamics.simulation.settings import HELD


def includes(source: Path) -> set[Path]:
    """The quoted includes of a C file, transitively (next to it)."""
    found: set[Path] = set()
    todo = [source]
    while todo:
        for name in re.findall(r'^#include "([^"]+)"', todo.pop().read_text(), re.M):
            path = source.parent / name
            if path not in found:
                found.add(path)
                todo.append(path)
    return found


def test_the_listed_headers_are_what_the_integrators_include():
    assert includes(radau.SOURCE) == set(radau.HEADERS)
    assert includes(rosenbrock.SOURCE) == set(radau.HEADERS)


class Decay(Component):
    """``x' = -x``."""

    def build(self, b) -> None:
        x = b.state("x", 1.0, "1", "decaying")
        b.der(x, -x)


class Keyed(Exception):
    """Raised instead of compiling, with the cache key's inputs."""


@pytest.mark.parametrize("module", [radau, rosenbrock])
def test_every_header_is_in_the_cache_key(module, monkeypatch):
    def capture(name, inputs, units):
        raise Keyed(inputs)

    monkeypatch.setattr(compiled, "shared_library", capture)
    sys = System("decay")
    sys.add(Decay("d"))
    with pytest.raises(Keyed) as caught:
        module.library(sys.flatten(), HELD)
    inputs = caught.value.args[0]
    for header in radau.HEADERS:
        assert header.read_bytes() in inputs, header.name
