"""The control-tension scene, shortened: LQI breaks the thread-tension bound, the NMPC and
the LMPC, which state it, hold it; the violation is reported per controller."""

import json
import re

import pytest

from sarcomere.scenarios import parse_scenario, resolve_scenario, run


def _short_tension_scene(keep: tuple[str, ...]) -> str:
    """control-tension in 1.0 s (the -6 mm step at 0.2 s), with the controllers ``keep``."""
    text = resolve_scenario("control-tension").read_text(encoding="utf-8")
    text = text.replace('stop_time = "2.5 s"', 'stop_time = "1.0 s"')
    text = text.replace('step_time = "0.5 s"', 'step_time = "0.2 s"')
    drop = "|".join(
        k
        for k in ("pid", "lqi", "lqi_ekf", "lmpc", "nmpc", "nmpc_ekf", "pid_preview")
        + ("lqi_informed", "lqi_ekf_informed")
        if k not in keep
    )
    return re.sub(rf"\[control\.controllers\.({drop})\]\n(\w.*\n)*", "", text)


@pytest.mark.slow  # over 0.8 s: the fast loop leaves it to the full suite
def test_lqi_breaks_the_tension_bound_the_mpcs_hold_it(tmp_path):
    sc = parse_scenario(_short_tension_scene(("lqi", "lmpc", "nmpc")), "tension-short.toml")
    assert set(sc.control["controllers"]) == {"lqi", "lmpc", "nmpc"}
    out = run(sc, tmp_path, quiet=True)
    m = out.metrics
    # LQI does not know the bound: the step throws the load up and the lowest thread
    # unloads by tens of mN, for several samples
    assert m["lqi_tension_violation_max_mN"] > 20, m
    assert m["lqi_tension_violation_time_s"] >= 0.03, m
    for key in ("nmpc", "lmpc"):  # stated in the prediction, held on the plant to 1 mN
        assert m[f"{key}_tension_violation_max_mN"] < 1.0, m
        assert m[f"{key}_tension_violation_time_s"] == 0, m
        assert m[f"{key}_rmse_mm"] < m["lqi_rmse_mm"], m
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["extra"]["estimators"] == {
        "lqi": "exact states",
        "lmpc": "exact states",
        "nmpc": "exact states",
    }
    assert summary["extra"]["tension_min_N"] == pytest.approx(0.2)


@pytest.mark.slow
def test_the_nmpc_on_the_ekf_holds_the_bound_backed_off_by_the_estimates_spread(tmp_path):
    """On the EKF's estimate the NMPC's bound is raised by one standard deviation of the
    estimated tension (``backoff``, ``EKF_BACKOFF``): the plant's threads then hold the
    0.2 N bound to 1 mN; without the back-off (``backoff = 0``, as before) the same
    controller breaks it by more (1.76 mN in the packaged scene)."""
    text = _short_tension_scene(("nmpc_ekf",))
    text += (
        '\n[control.controllers.nmpc_ekf_bare]\ntype = "nmpc"\nestimator = "ekf"\nbackoff = 0.0\n'
    )
    out = run(parse_scenario(text, "tension-ekf.toml"), tmp_path, quiet=True)
    m = out.metrics
    assert m["nmpc_ekf_tension_violation_max_mN"] < 1.0, m
    assert m["nmpc_ekf_bare_tension_violation_max_mN"] > 1.0, m
    assert m["nmpc_ekf_fallbacks"] == 0, m
