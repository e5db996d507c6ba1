"""Untrusted FMU archives: crafted bad archives are refused with one clear line each, and
the extraction folder never outlives its use."""

from __future__ import annotations

import re
import stat
import tempfile
import zipfile
from pathlib import Path

import pytest

from sarcomere.fmu import archive
from sarcomere.fmu.archive import FmuArchiveError, open_fmu

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)


def _rewrite(good: Path, out: Path, *, drop=(), replace=None, extra=()) -> Path:
    """A copy of ``good`` without the entries starting with ``drop``, with
    ``replace(name, data) -> data`` applied and ``extra`` (ZipInfo or name, data) added."""
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename.startswith(tuple(drop)):
                continue
            data = src.read(info)
            dst.writestr(info, replace(info.filename, data) if replace else data)
        for name, data in extra:
            dst.writestr(name, data)
    return out


def _description(edit):
    def replace(name: str, data: bytes) -> bytes:
        return edit(data) if name == "modelDescription.xml" else data

    return replace


def _symlink() -> zipfile.ZipInfo:
    info = zipfile.ZipInfo("resources/link")
    info.external_attr = (stat.S_IFLNK | 0o777) << 16
    return info


BAD = {
    "traversal": (
        {"extra": [("../evil.txt", b"x")]},
        "entry '../evil.txt' escapes the extraction folder",
    ),
    "absolute": ({"extra": [("/tmp/evil.txt", b"x")]}, "escapes the extraction folder"),
    "symlink": ({"extra": [(_symlink(), b"/etc/passwd")]}, "is a symbolic link"),
    "bomb": (
        {"extra": [("resources/zeros.bin", bytes(8 * 2**20))]},
        "entry 'resources/zeros.bin' expands",
    ),
    "no binary": ({"drop": ["binaries/"]}, "no binary for this platform (binaries/linux64/"),
    "no description": ({"drop": ["modelDescription.xml"]}, "no modelDescription.xml"),
    "unknown version": (
        {"replace": _description(lambda d: d.replace(b'fmiVersion="2.0"', b'fmiVersion="9.1"'))},
        "unknown FMI version '9.1'",
    ),
    "malformed xml": (
        {"replace": _description(lambda d: d[: len(d) // 2])},
        "malformed modelDescription.xml",
    ),
    "schema": (
        {
            "replace": _description(
                lambda d: re.sub(rb"<ModelStructure>.*</ModelStructure>", b"", d, flags=re.S)
            )
        },
        "malformed modelDescription.xml",
    ),
}


@pytest.fixture
def own_tmp(tmp_path, monkeypatch) -> Path:
    """This test's own temporary folder for the extraction folders (what other processes
    leave in the machine's is none of its business)."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


@pytest.mark.parametrize("case", list(BAD))
def test_a_crafted_bad_archive_is_refused_in_one_line(case, step_fmu, tmp_path, own_tmp):
    edits, message = BAD[case]
    bad = _rewrite(step_fmu, tmp_path / "bad.fmu", **edits)
    with pytest.raises(FmuArchiveError) as info:
        with open_fmu(bad):
            pass
    text = str(info.value)
    assert text.startswith(f"FMU '{bad}': ") and message in text, text
    assert "\n" not in text
    assert not list(own_tmp.glob("sarcomere-fmu-*"))  # the extraction folder is gone


def _identifier(ident: str):
    return _description(lambda d: re.sub(rb'modelIdentifier="[^"]*"', ident.encode(), d))


def test_a_model_identifier_leading_out_of_the_archive_is_refused(
    step_fmu, tmp_path, own_tmp, monkeypatch
):
    """``modelIdentifier = "../../../evil"`` names own_tmp/evil.so from the extraction
    folder's binaries/linux64: a library outside the archive, never to be loaded."""
    (own_tmp / "evil.so").write_bytes(b"\x7fELF")
    bad = _rewrite(
        step_fmu, tmp_path / "bad.fmu", replace=_identifier('modelIdentifier="../../../evil"')
    )
    with pytest.raises(
        FmuArchiveError, match=r"modelIdentifier '\.\./\.\./\.\./evil' is not a C identifier"
    ):
        with open_fmu(bad):
            pass
    monkeypatch.setattr(archive, "IDENTIFIER", re.compile(".*"))  # the second line of defence
    with pytest.raises(
        FmuArchiveError, match=r"binaries/linux64/\.\./\.\./\.\./evil\.so lies outside"
    ):
        with open_fmu(bad):
            pass
    assert not list(own_tmp.glob("sarcomere-fmu-*"))


def test_a_huge_model_description_is_refused_before_it_is_parsed(step_fmu, monkeypatch):
    def parse(*args, **kwargs):
        raise AssertionError("parsed")

    monkeypatch.setattr(archive.ElementTree, "parse", parse)
    monkeypatch.setattr(archive, "read_model_description", parse)
    monkeypatch.setattr(archive, "MAX_DESCRIPTION_BYTES", 1000)
    with pytest.raises(
        FmuArchiveError, match=r"modelDescription.xml is \d+ bytes, more than 1000$"
    ):
        with open_fmu(step_fmu):
            pass


def test_declared_sizes_are_bounded(step_fmu, monkeypatch):
    monkeypatch.setattr(archive, "MAX_UNPACKED_BYTES", 1000)
    with pytest.raises(FmuArchiveError, match="bytes unpacked, more than 1000"):
        with open_fmu(step_fmu):
            pass


def test_archive_size_and_kind_are_checked(tmp_path, monkeypatch, step_fmu):
    text = tmp_path / "x.fmu"
    text.write_text("not a zip")
    with pytest.raises(FmuArchiveError, match="not a zip archive"):
        with open_fmu(text):
            pass
    with pytest.raises(FmuArchiveError, match="no such file"):
        with open_fmu(tmp_path / "missing.fmu"):
            pass
    expected = r"; expected an FMU file \(a \.fmu zip archive\)$"
    folder = tmp_path / "folder.fmu"
    folder.mkdir()
    with pytest.raises(FmuArchiveError, match="': a folder" + expected):
        with open_fmu(folder):
            pass
    with pytest.raises(FmuArchiveError, match="not a regular file .*" + expected):
        with open_fmu("/dev/null"):
            pass
    (tmp_path / "dangling.fmu").symlink_to(tmp_path / "gone.fmu")
    with pytest.raises(FmuArchiveError, match="a broken symbolic link" + expected):
        with open_fmu(tmp_path / "dangling.fmu"):
            pass
    monkeypatch.setattr(archive, "MAX_ARCHIVE_BYTES", 1000)
    with pytest.raises(FmuArchiveError, match=r"bytes, more than 1000$"):
        with open_fmu(step_fmu):
            pass


def test_a_good_archive_opens_in_a_private_folder_removed_afterwards(step_fmu):
    with open_fmu(step_fmu) as fmu:
        folder = fmu.folder
        assert fmu.fmi_version == 2
        assert fmu.description.coSimulation.modelIdentifier
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
        assert (folder / "binaries" / "linux64").is_dir()
    assert not folder.exists()


def test_an_fmi3_archive_opens(iso_fmu3):
    with open_fmu(iso_fmu3) as fmu:
        assert fmu.fmi_version == 3
        assert (fmu.folder / "binaries" / "x86_64-linux").is_dir()
