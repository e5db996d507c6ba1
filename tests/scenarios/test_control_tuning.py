"""The MPC tuning study's choice rule (benchmarks/studies/mpc_tuning.py) on made-up rows,
and the grid's scene text: what the study runs is the packaged scene with its controllers
replaced."""

import pytest

from benchmarks.studies.mpc_tuning import (
    OVERSHOOT_MAX_PCT,
    choose,
    distance_from_defaults,
    excess,
    point_key,
    scene_text,
    score,
)
from sarcomere.controllers.nmpc import NMPCSettings
from sarcomere.scenarios.loader import parse_scenario

LQI = {
    "control-length": {"rmse_mm": 1.0, "overshoot_pct": 18.0},
    "control-tension": {"rmse_mm": 2.0, "tension_violation_max_mN": 65.0},
}


def rows(length_rmse, overshoot, tension_rmse, violation_mN, fallbacks=0.0):
    return {
        "control-length": {
            "rmse_mm": length_rmse,
            "overshoot_pct": overshoot,
            "tension_violation_max_mN": 0.0,
            "fallbacks": fallbacks,
        },
        "control-tension": {
            "rmse_mm": tension_rmse,
            "overshoot_pct": 0.0,
            "tension_violation_max_mN": violation_mN,
            "fallbacks": 0.0,
        },
    }


def test_the_lowest_admissible_score_wins():
    candidates = {
        "fast_overshoots": rows(0.5, 12.0, 0.5, 0.0),  # best rmse, overshoot 12 % > 10 %
        "breaks_bound": rows(0.6, 5.0, 0.6, 1.5),  # 1.5 mN > 1 mN
        "falls_back": rows(0.6, 5.0, 0.6, 0.0, fallbacks=1),
        "good": rows(0.8, 9.0, 1.0, 0.9),  # score (0.8 + 0.5) / 2 = 0.65
        "better": rows(0.7, 10.0, 1.0, 1.0),  # on both bounds: admissible, 0.6
    }
    weights = dict.fromkeys(candidates, 0.0)
    assert score(candidates["good"], LQI) == pytest.approx(0.65)
    assert [k for k in candidates if excess(candidates[k]) == 0] == ["good", "better"]
    assert choose(candidates, LQI, weights) == "better"
    # scores equal to three decimals tie; a tie goes to the point nearest the defaults
    tie = {"far": rows(0.7, 5, 1.0, 0), "near": rows(0.7002, 5, 1.0, 0)}
    assert choose(tie, LQI, {"far": 2.0, "near": 0.5}) == "near"
    assert distance_from_defaults(
        {
            "type": "nmpc",
            "weight_y": 10 * NMPCSettings().weight_y,
            "weight_du": NMPCSettings().weight_du / 100,
        }
    ) == pytest.approx(3.0)


def test_without_an_admissible_point_the_least_excess_wins():
    candidates = {
        "far": rows(0.5, 2 * OVERSHOOT_MAX_PCT, 0.5, 0.0),  # excess 1.0
        "near": rows(0.9, 11.0, 0.9, 1.2),  # excess 0.1 + 0.2
    }
    assert excess(candidates["far"]) == pytest.approx(1.0)
    assert excess(candidates["near"]) == pytest.approx(0.3)
    assert choose(candidates, LQI, dict.fromkeys(candidates, 1e-9)) == "near"


def test_scene_text_runs_lqi_and_the_grid_points_on_the_packaged_scene():
    key = point_key("nmpc", 20, 1e6, 3e-10)
    assert key == "nmpc_h20_y1e6_du3em10"
    own = {"type": "nmpc", "horizon": 20, "weight_y": 1e6, "weight_du": 3e-10}
    sc = parse_scenario(scene_text("control-tension", {key: own}), "t.toml")
    assert sc.control["controllers"] == {"lqi": {}, key: own}
    assert sc.control["tension_min"] == "0.2 N"
    assert sc.simulation.stop_time == 2.5
