"""Participants that cannot start: an FMU whose binary does not load or whose instance is
not created is a ParticipantError (CosimError in the master) naming the FMU and what
failed, after the archive's own checks; a native participant reads its outputs at the
inputs it was started with."""

from __future__ import annotations

import gc
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from benchmarks.studies import cosim_coupling as study
from sarcomere.dynamics.errors import ParameterError
from sarcomere.fmu.archive import FmuArchiveError, open_fmu
from sarcomere.fmu.cosim import Connection, CosimError, cosimulate
from sarcomere.fmu.participants import FmuParticipant, NativeParticipant, ParticipantError


def _craft(src: Path, dst: Path, change) -> Path:
    """A copy of the FMU ``src`` with each entry's bytes passed through ``change(name,
    data)`` (None drops the entry)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = change(item.filename, zin.read(item))
            if data is not None:
                zout.writestr(item, data)
    return dst


def _corrupt_binary(name: str, data: bytes) -> bytes:
    return b"\x7fELF but not a shared library" * 64 if name.endswith(".so") else data


def _other_token(name: str, data: bytes) -> bytes:
    if name != "modelDescription.xml":
        return data
    text = data.decode()
    key = 'guid="' if 'guid="' in text else 'instantiationToken="'
    start = text.index(key) + len(key)
    return (
        text[:start] + "{00000000-0000-0000-0000-000000000000}" + text[text.index('"', start) :]
    ).encode()


def test_a_binary_that_does_not_load_names_the_fmu(iso_fmu, tmp_path):
    crafted = _craft(iso_fmu, tmp_path / "corrupt.fmu", _corrupt_binary)
    cwd = os.getcwd()
    with open_fmu(crafted) as fmu:  # the archive is sound: its checks pass
        with pytest.raises(ParticipantError) as info:
            FmuParticipant(fmu, "m")
    err = info.value
    assert err.participant == "FMU 'm' (corrupt.fmu)" and err.status == "fatal"
    assert "loading its binary failed" in str(err) and ".so" in str(err)
    assert os.getcwd() == cwd  # fmpy's chdir into the extraction folder is undone


def test_the_archive_checks_come_before_loading(iso_fmu, tmp_path):
    crafted = _craft(
        iso_fmu, tmp_path / "nobinary.fmu", lambda n, d: None if n.endswith(".so") else d
    )
    with pytest.raises(FmuArchiveError, match="binaries/linux64"):
        with open_fmu(crafted):
            pass


@pytest.mark.parametrize("fixture", ["iso_fmu", "iso_fmu3"])
def test_an_instance_that_is_not_created_stops_the_run_at_the_start(request, tmp_path, fixture):
    """The GUID (FMI 3.0: instantiation token) is not the binary's: instantiate returns
    NULL, with the FMU's own message."""
    crafted = _craft(request.getfixturevalue(fixture), tmp_path / "token.fmu", _other_token)
    with open_fmu(crafted) as fmu:
        with pytest.raises(CosimError) as info:
            cosimulate([FmuParticipant(fmu, "m")], stop_time=0.1, step=0.01)
    err = info.value
    assert err.participant == "FMU 'm' (token.fmu)" and err.status == "fatal"
    assert err.time == 0.0 and len(err.result.index) == 0
    assert "instantiate failed" in str(err)
    assert "is not this FMU's" in str(err)  # the FMU's log message, passed on


def test_a_native_output_that_feeds_through_reads_at_the_start_inputs():
    """The load's spring tension depends on its input position directly: read after
    ``start`` it is the tension at the start input (the load's weight at equilibrium),
    not at the model's default input (0 m: 11.9 N here)."""
    load = NativeParticipant(study.load_participant_model(200.0), "load")
    load.start(0.0, {"drive.s": 0.05})
    got = load.get(["sensor.f", "drive.s", "mass.s"])
    assert got["drive.s"] == 0.05
    assert got["sensor.f"] == pytest.approx(study.start_force(), rel=1e-9)
    assert got["mass.s"] == pytest.approx(0.05 + study.REST_M + study.start_force() / 200.0)


def test_start_inputs_close_a_loop_at_its_equilibrium():
    """With the coupling force of the joint equilibrium given, the split system starts
    at rest: nothing moves over a few steps without a command change."""
    r = study.cosimulate_split(200.0, 1e-3, "jacobi", "hold", (2e4, 2e4, 0.0), 0.005)
    s = r["load.mass.s"]
    assert np.ptp(s) < 1e-9 * abs(s[0])
    np.testing.assert_allclose(r["load.sensor.f"], study.start_force(), rtol=1e-6)


def test_start_inputs_must_be_a_loop_input_driven_later():
    parts = [
        NativeParticipant(study.muscle_participant_model(), "muscle"),
        NativeParticipant(study.load_participant_model(200.0), "load"),
    ]
    with pytest.raises(ParameterError, match="driver starts after it"):
        cosimulate(
            parts,
            study.CONNECTIONS,
            stop_time=0.01,
            step=0.01,
            start_inputs={"load.drive.s": 0.05},  # its driver, the muscle, starts first
        )
    with pytest.raises(ParameterError, match="driver starts after it"):
        cosimulate(
            parts,
            [Connection("load.sensor.f", "muscle.pull.f")],
            stop_time=0.01,
            step=0.01,
            start_inputs={"muscle.regulator.p_cmd": 1e4},  # not connected
        )


def test_fmi2_messages_reach_their_own_participant_when_several_live_and_one_is_gone(iso_fmu):
    """fmpy's printf proxy has one process-wide target: each FMI 2.0 message must still
    reach the participant whose instance sent it, also after another one was freed and
    collected (a per-instance logger crashed the process there)."""
    with open_fmu(iso_fmu) as fmu:
        a, b, c = (FmuParticipant(fmu, name) for name in "abc")
        for p in (a, b, c):
            p.start(0.0, {})
        c.close()
        del c
        gc.collect()
        with pytest.raises(ParticipantError) as info:
            a.set({"regulator.p_cmd": 1e9})
        assert str(info.value).startswith("FMU 'a'")
        assert "regulator.p_cmd = 1000000000 is outside" in str(info.value)
        with pytest.raises(ParticipantError, match="FMU 'b'.*is outside"):
            b.set({"regulator.p_cmd": -1.0})
        a.close()
        b.close()
