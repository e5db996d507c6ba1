"""step-50g runs at the instant-pneumatics levels: every signal it plots exists, and the
chambers read the regulator's outlet pressure."""

from pathlib import Path

import numpy as np
import pytest

from sarcomere.scenarios import parse_scenario, transient
from sarcomere.scenarios.loader import packaged_scenarios


@pytest.mark.parametrize("level", ["instant_pneumatics", "instant_quasi_static"])
def test_step_50g_runs_at_the_instant_levels(level):
    text = packaged_scenarios()["step-50g"].read_text()
    sc = parse_scenario(text.replace('fidelity = "full"', f'fidelity = "{level}"'), "s.toml")
    run = transient.run_transient(sc, Path("."))
    assert run.fidelity == level
    res = run.results["main"]
    for k in (1, 3):
        p = res[f"myofibril.aps{k}.chamber.p_gauge"]
        np.testing.assert_array_equal(p, res["regulator.p_out"])
    assert np.ptp(res["myofibril.actin3.T"]) > 0.1
