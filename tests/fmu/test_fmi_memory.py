"""The FMU's C wrapper under AddressSanitizer and UBSan: a small C driver
(``c/misuse_driver.c``) compiled with the FMU's own sources misuses the FMI 2.0 API one
case per process (a crash, a sanitizer report or a hang fails only its case), and each case
must end in an error status with a message, never in a read of freed memory, undefined
behaviour or an endless loop."""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from sarcomere.fmu.export import fmi_headers

pytestmark = pytest.mark.slow  # exports, builds and runs FMUs: the full suite (CI)

DRIVER = Path(__file__).parent / "c" / "misuse_driver.c"
SANITIZE = ["-fsanitize=address,undefined", "-fsanitize=float-cast-overflow"]
OK, ERROR = 0, 3


def _gcc_sanitizes(tmp: Path) -> bool:
    probe = tmp / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    cmd = ["gcc", *SANITIZE, str(probe), "-o", str(tmp / "probe")]
    built = subprocess.run(cmd, capture_output=True, check=False).returncode == 0
    return built and subprocess.run([str(tmp / "probe")], check=False).returncode == 0


@pytest.fixture(scope="module")
def driver(iso_fmu, tmp_path_factory) -> Path:
    """The driver linked with the isometric FMU's sources (FMI 2.0, n = 1), sanitized."""
    tmp = tmp_path_factory.mktemp("asan")
    if shutil.which("gcc") is None or not _gcc_sanitizes(tmp):
        pytest.skip("gcc with AddressSanitizer and UBSan is not available here")
    with zipfile.ZipFile(iso_fmu) as zf:
        zf.extractall(tmp / "fmu")
    src = tmp / "fmu" / "sources"
    exe = tmp / "driver"
    cmd = ["gcc", "-std=c11", "-g", "-O1", "-fno-omit-frame-pointer", *SANITIZE]
    cmd += ["-fno-sanitize-recover=all", "-I", str(src), "-I", str(fmi_headers())]
    cmd += [*map(str, sorted(src.glob("*.c"))), str(DRIVER), "-o", str(exe), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return exe


def run(driver: Path, case: str) -> tuple[dict[str, int], list[str]]:
    """Runs one case: the status of each call by name and the log messages."""
    try:
        done = subprocess.run(
            [str(driver), case], capture_output=True, text=True, timeout=60, check=False
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{case}: the FMU did not return within 60 s")
    assert done.returncode == 0, f"{case}: exit {done.returncode}\n{done.stderr[-3000:]}"
    statuses, messages = {}, []
    for line in done.stdout.splitlines():
        kind, rest = line.split(" ", 1)
        if kind == "status":
            name, status = rest.split()
            statuses[name] = int(status)
        elif kind == "log":
            messages.append(rest)
    return statuses, messages


def test_a_freed_state_is_refused_not_read(driver):
    statuses, messages = run(driver, "freed_state")
    assert statuses == {
        "get": OK,
        "free": OK,
        "set_freed": ERROR,
        "serialize_freed": ERROR,
        "free_again": ERROR,
    }
    assert "3 logStatusError fmi2SetFMUstate: this FMU state was freed already" in messages


def test_a_bogus_or_foreign_state_pointer_is_refused(driver):
    statuses, messages = run(driver, "bogus_state")
    assert statuses == {"set_bogus": ERROR, "set_foreign": ERROR, "get_into_bogus": ERROR}
    assert messages.count("3 logStatusError fmi2SetFMUstate: not a state of this FMU") == 2
    assert "3 logStatusError fmi2GetFMUstate: not a state of this FMU" in messages


def test_freeing_an_instance_frees_its_states(driver):
    statuses, messages = run(driver, "state_of_freed_instance")
    assert statuses == {"get": OK, "set_in_b": ERROR}
    assert "3 logStatusError fmi2SetFMUstate: this FMU state was freed already" in messages


def test_an_absurd_step_is_refused_at_once(driver):
    statuses, messages = run(driver, "huge_step")
    assert statuses == {"step_1e20": ERROR, "step_ok": OK}  # refused, the instance still runs
    assert any(
        "step size 1e+20 s ends at t = 1e+20 s, outside the FMU's time range" in m for m in messages
    ), messages


def test_a_step_past_the_stop_time_is_refused(driver):
    statuses, messages = run(driver, "past_stop")
    assert statuses == {"step_to_0.005": OK, "step_to_0.015": ERROR, "step_to_0.01": OK}
    assert any("past the stop time 0.01 s given at set-up" in m for m in messages), messages


@pytest.mark.parametrize("case", ["huge_mode", "fraction_mode"])
def test_a_deserialised_mode_is_range_checked_before_its_cast(driver, case):
    statuses, messages = run(driver, case)
    assert statuses == {"serialize": OK, "deserialize": ERROR}
    assert "3 logStatusError fmi2DeSerializeFMUstate: refused (unknown mode)" in messages


def test_a_log_category_that_is_not_one_bit_returns(driver):
    statuses, messages = run(driver, "log_category")
    assert statuses == {"logged": OK}
    assert messages == ["1 logStatusWarning combined category"]  # the first bit's name
    # a category no bit of which is on is not logged


def test_no_fixed_cap_on_instances(driver):
    statuses, messages = run(driver, "many_instances")
    assert statuses == {"last_step": OK}
    assert not [m for m in messages if m.startswith("3 ")], messages[:3]
