"""Open an untrusted FMU archive safely: check it, extract it into a private temporary
folder, read its model description through fmpy, and clean the folder up.

Checks, in order, each failing with one :class:`FmuArchiveError` line naming the archive
and the problem:

* the file is a zip archive of at most :data:`MAX_ARCHIVE_BYTES`;
* at most :data:`MAX_ENTRIES` entries; no entry is absolute, climbs out with ``..``, or is
  a symbolic link (nothing may land outside the extraction folder);
* the declared uncompressed sizes sum to at most :data:`MAX_UNPACKED_BYTES`, and no entry
  larger than :data:`RATIO_FLOOR_BYTES` expands more than :data:`MAX_RATIO` times (zip
  bombs); extraction never writes more than an entry declares (``zipfile`` stops at the
  declared size and checks the CRC);
* ``modelDescription.xml`` exists, is at most :data:`MAX_DESCRIPTION_BYTES` (checked before
  any parsing), is well-formed XML whose root is
  ``fmiModelDescription`` with ``fmiVersion`` 2.0 or 3.x, and fmpy reads it;
* every model identifier is a C identifier (as the FMI schema requires: it names the
  binary and prefixes its functions), so the binary's path stays inside the extraction
  folder (checked on the resolved path too);
* the FMU has the interface asked for (Co-Simulation by default) and the binary of its
  model identifier for this platform
  (``binaries/linux64`` for FMI 2.0, ``binaries/x86_64-linux`` for FMI 3.0).
"""

from __future__ import annotations

import re
import shutil
import stat
import tempfile
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from xml.etree import ElementTree

from fmpy import read_model_description
from fmpy.model_description import ModelDescription

from sarcomere.dynamics.errors import SarcomereError

MAX_ARCHIVE_BYTES = 256 * 2**20
"""Largest accepted archive file [bytes]."""

MAX_UNPACKED_BYTES = 1024 * 2**20
"""Largest accepted sum of the entries' declared uncompressed sizes [bytes]."""

MAX_ENTRIES = 10_000
"""Most entries in one archive."""

MAX_RATIO = 200.0
"""Largest accepted expansion (uncompressed / compressed size) of an entry larger than
:data:`RATIO_FLOOR_BYTES`; generated C and shared libraries compress some 3 to 10 times."""

MAX_DESCRIPTION_BYTES = 8 * 2**20
"""Largest accepted ``modelDescription.xml`` [bytes], checked before it is parsed (parsing
and validating a 60 MB one cost 43 s of CPU, issue 24; the largest this project writes, an
NMPC controller FMU with its law's memory as variables, 0.39 MB at n = 3, horizon 20)."""

IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
"""A model identifier: a C identifier (the FMI schema's pattern)."""

RATIO_FLOOR_BYTES = 2**20
"""Entries up to this uncompressed size [bytes] are not held to :data:`MAX_RATIO`."""

PLATFORMS = {2: "linux64", 3: "x86_64-linux"}
"""The binaries folder of this platform by FMI major version."""


INTERFACES = {"coSimulation": "Co-Simulation", "modelExchange": "Model Exchange"}
"""The interfaces :func:`open_fmu` checks for, by fmpy's attribute name."""


class FmuArchiveError(SarcomereError):
    """An FMU archive was refused (unsafe, malformed, or not runnable here)."""


@dataclass(frozen=True)
class OpenedFmu:
    """A checked FMU extracted into ``folder`` (removed when the context ends).

    Attributes
    ----------
    path : pathlib.Path
        The archive.
    folder : pathlib.Path
        The private extraction folder.
    description : fmpy.model_description.ModelDescription
        The model description as fmpy reads it.
    fmi_version : int
        2 or 3.
    """

    path: Path
    folder: Path
    description: ModelDescription
    fmi_version: int


def _fail(path: Path, problem: str) -> FmuArchiveError:
    return FmuArchiveError(f"FMU '{path}': {problem}")


def _check_entries(path: Path, zf: zipfile.ZipFile) -> None:
    infos = zf.infolist()
    if len(infos) > MAX_ENTRIES:
        raise _fail(path, f"{len(infos)} entries, more than {MAX_ENTRIES}")
    total = 0
    for info in infos:
        name = info.filename
        parts = PurePosixPath(name.replace("\\", "/")).parts
        if name.startswith(("/", "\\")) or ".." in parts or (parts and ":" in parts[0]):
            raise _fail(path, f"entry '{name}' escapes the extraction folder")
        if stat.S_ISLNK(info.external_attr >> 16):
            raise _fail(path, f"entry '{name}' is a symbolic link")
        total += info.file_size
        if info.file_size > RATIO_FLOOR_BYTES:
            ratio = info.file_size / max(info.compress_size, 1)
            if ratio > MAX_RATIO:
                raise _fail(
                    path, f"entry '{name}' expands {ratio:.0f} times (at most {MAX_RATIO:.0f})"
                )
    if total > MAX_UNPACKED_BYTES:
        raise _fail(path, f"entries declare {total} bytes unpacked, more than {MAX_UNPACKED_BYTES}")
    xml = max((i.file_size for i in infos if i.filename == "modelDescription.xml"), default=0)
    if xml > MAX_DESCRIPTION_BYTES:
        raise _fail(path, f"modelDescription.xml is {xml} bytes, more than {MAX_DESCRIPTION_BYTES}")


def _fmi_version(path: Path, folder: Path) -> int:
    xml = folder / "modelDescription.xml"
    if not xml.is_file():
        raise _fail(path, "no modelDescription.xml")
    try:
        root = ElementTree.parse(xml).getroot()
    except ElementTree.ParseError as err:
        raise _fail(path, f"malformed modelDescription.xml ({err})") from None
    if root.tag != "fmiModelDescription":
        raise _fail(path, f"modelDescription.xml has root <{root.tag}>, not fmiModelDescription")
    version = root.get("fmiVersion", "")
    if version == "2.0":
        return 2
    if version.startswith("3."):
        return 3
    raise _fail(path, f"unknown FMI version '{version}' (2.0 or 3.x)")


def _binary(path: Path, folder: Path, md: ModelDescription, interface: str, version: int) -> None:
    """Refuses a model identifier that is not a C identifier (or whose binary would resolve
    outside ``folder``) and a missing binary of the interface used."""
    for kind in (md.coSimulation, md.modelExchange):
        ident = "" if kind is None else kind.modelIdentifier
        if kind is not None and not IDENTIFIER.fullmatch(ident or ""):
            raise _fail(path, f"modelIdentifier {ident!r} is not a C identifier")
    kind = getattr(md, interface)
    if kind is None:
        raise _fail(path, f"no {INTERFACES[interface]} interface")
    binary = Path("binaries") / PLATFORMS[version] / f"{kind.modelIdentifier}.so"
    if not (folder / binary).resolve().is_relative_to(folder.resolve()):
        raise _fail(path, f"the binary {binary} lies outside the archive")
    if not (folder / binary).is_file():
        raise _fail(path, f"no binary for this platform ({binary})")


def _not_a_file(path: Path) -> str:
    """What ``path`` is instead of the FMU file (a .fmu zip archive) expected."""
    if path.is_dir():
        what = "a folder"
    elif path.exists():
        what = "not a regular file (a device, FIFO or socket)"
    elif path.is_symlink():
        what = "a broken symbolic link"
    else:
        return "no such file"
    return f"{what}; expected an FMU file (a .fmu zip archive)"


@contextmanager
def open_fmu(path: str | Path, interface: str = "coSimulation") -> Iterator[OpenedFmu]:
    """Check and extract the FMU at ``path``; the folder is removed when the block ends.

    ``interface``: the one the caller will use, "coSimulation" or "modelExchange".

    Raises
    ------
    FmuArchiveError
        The archive fails one of the checks of this module.

    Examples
    --------
    >>> with open_fmu("step-50g.fmu") as fmu:  # doctest: +SKIP
    ...     fmu.fmi_version, fmu.description.coSimulation.modelIdentifier
    (2, 'myofibril')
    """
    path = Path(path)
    if not path.is_file():
        raise _fail(path, _not_a_file(path))
    size = path.stat().st_size
    if size > MAX_ARCHIVE_BYTES:
        raise _fail(path, f"{size} bytes, more than {MAX_ARCHIVE_BYTES}")
    if not zipfile.is_zipfile(path):
        raise _fail(path, "not a zip archive")
    folder = Path(tempfile.mkdtemp(prefix="sarcomere-fmu-"))  # mode 0700: private
    try:
        with zipfile.ZipFile(path) as zf:
            _check_entries(path, zf)
            try:
                zf.extractall(folder)
            except (zipfile.BadZipFile, OSError) as err:
                raise _fail(path, f"cannot be extracted ({err})") from None
        version = _fmi_version(path, folder)
        try:
            md = read_model_description(str(folder), validate=True)
        except Exception as err:  # fmpy raises plain Exceptions for schema problems
            problem = " ".join(str(err).split())[:300]
            raise _fail(path, f"malformed modelDescription.xml ({problem})") from None
        _binary(path, folder, md, interface, version)
        yield OpenedFmu(path, folder, md, version)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
