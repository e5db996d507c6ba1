"""The packaged fit ``fit-paper``: the calibration as a fit file. From the CLI and from
Python it gives calibrate()'s three parameters to 1e-8 (calibrate() run here, not a
stored number), its data are the calibration's targets, and with ``aps.L_r`` fitted too
its summary flags the compliance split as structurally non-identifiable."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from sarcomere.dynamics import calibration
from sarcomere.dynamics.errors import ParameterError, SolverError
from sarcomere.scenarios.calibrate import calibrate_file
from sarcomere.scenarios.cli import main
from sarcomere.scenarios.fit.data import read_table
from sarcomere.scenarios.fit.run import Fit
from sarcomere.scenarios.fit.spec import load_fit

FITS = Path(__file__).parents[2] / "scenarios" / "fits"
FIT_PAPER = FITS / "fit-paper.toml"


def test_data_are_the_calibration_targets():
    """The three CSV values, in SI as the fit reads them, are calibration.TARGETS (one
    number typed twice must not drift), each measured against its reference."""
    spec = load_fit(FIT_PAPER)
    got = {}
    for e in spec.experiments:
        table = read_table(e.data, time_series=False)
        (signal,) = e.outputs
        unit = "1" if e.reference.form == "ratio" else "N"
        got[e.name] = (float(table.si(signal, unit)[0]), float(table.si("pressure", "Pa")[0]))
    assert got == {
        "isometric-1aps": (calibration.TARGETS["force_n1_0p1MPa_N"], calibration.P_TEST),
        "contraction-0g": (calibration.TARGETS["length_ratio_0g_0p1MPa"], calibration.P_TEST),
        "contraction-100g": (calibration.TARGETS["length_ratio_100g_0MPa"], 0.0),
    }
    forms = {e.name: (e.reference.form, e.reference.experiment) for e in spec.experiments}
    assert forms == {
        "isometric-1aps": ("difference", None),
        "contraction-0g": ("ratio", None),
        "contraction-100g": ("ratio", "contraction-0g"),
    }


@pytest.fixture(scope="module")
def calibrated() -> dict[str, float]:
    return calibration.calibrate().fitted


@pytest.mark.slow
def test_cli_and_python_give_calibrates_parameters(calibrated, tmp_path):
    assert main(["fit", str(FIT_PAPER), "--out", str(tmp_path / "cli"), "--no-plots"]) == 0
    summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    from_cli = {e["name"]: e["value"] for e in summary["estimates"]}
    res = Fit.from_file(FIT_PAPER).run(tmp_path / "py", plots=False, profiles=False)
    from_python = {k: v for k, (v, _) in res.estimates.items()}
    for got in (from_cli, from_python):
        assert set(got) == {f"aps.{k}" for k in calibrated}
        for k, v in calibrated.items():
            assert got[f"aps.{k}"] == pytest.approx(v, rel=1e-8, abs=0)
    assert [e["verdict"] for e in summary["estimates"]] == ["identifiable"] * 3
    assert summary["cost_chi2"] < 1e-12  # three numbers, three parameters: an exact fit


@pytest.mark.slow
def test_compliance_split_flagged_when_L_r_is_fitted(tmp_path):
    folder = tmp_path / "fits"
    shutil.copytree(FITS, folder)
    path = folder / "fit-paper.toml"
    text = path.read_text()
    extra = '[parameters."aps.L_r"]\nstart = "20 mm"\nbounds = ["4 mm", "40 mm"]\n\n'
    path.write_text(text.replace('[noise."sensor.f"]', extra + '[noise."sensor.f"]', 1))
    Fit.from_file(path).run(tmp_path / "out", plots=False, profiles=False)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    verdicts = {e["name"]: e for e in summary["estimates"]}
    assert verdicts["aps.L_r"]["verdict"] == "structurally non-identifiable"
    assert "aps.L_r^" in verdicts["aps.L_r"]["why"] and "aps.k_s^" in verdicts["aps.L_r"]["why"]
    # one flat direction: the smallest singular value zero against the largest
    sv = summary["singular_values"]
    assert min(sv) < 1e-8 * max(sv)
    assert summary["cost_chi2"] < 1e-12  # every member of the family meets the targets


@pytest.mark.slow
def test_sarcomere_calibrate_runs_the_packaged_file(calibrated, tmp_path, monkeypatch):
    """`sarcomere calibrate` fits through fit-paper.toml (one home for fitting): the
    status names the file, the parameters are calibrate()'s; a file whose data moved is
    refused by the independent check, not reported as the calibration."""
    assert main(["calibrate", "--out", str(tmp_path / "cal")]) == 0
    record = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert "fit file 'fit-paper'" in record["status"]
    for k, v in calibrated.items():
        assert record["fitted"][k]["value"] == pytest.approx(v, rel=1e-8, abs=0)
    folder = tmp_path / "fits"
    shutil.copytree(FITS, folder)
    csv = folder / "data" / "paper-contraction-0g.csv"
    csv.write_text(csv.read_text().replace("0.1,0.875", "0.1,0.88"))
    with pytest.raises(SolverError, match="targets other than calibration.TARGETS"):
        calibrate_file(folder / "fit-paper.toml")


def test_calibrate_file_refuses_other_parameters(tmp_path):
    folder = tmp_path / "fits"
    shutil.copytree(FITS, folder)
    path = folder / "fit-paper.toml"
    path.write_text(path.read_text().replace('"aps.k_s"]', '"aps.C1"]', 1))
    path.write_text(
        path.read_text().replace(
            'start = "694 N/m"\nbounds = ["35 N/m", "14000 N/m"]',
            'start = "0.096 MPa"\nbounds = ["0.01 MPa", "1 MPa"]',
        )
    )
    with pytest.raises(ParameterError, match="estimates of aps.A_p, aps.A_r, aps.k_s"):
        calibrate_file(path)
