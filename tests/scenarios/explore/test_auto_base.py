"""Issue 24, bug 2: a packaged ``*-auto`` scene as a study base. Below the rule's
REDUCED_FROM_N units the study runs, every sample at full (the auto rule), and says so;
from it (auto would predict each run's level) it is refused saying what to write in the
study file, and runs once the study file names a level."""

import textwrap

import numpy as np
import pytest

from sarcomere.dynamics.errors import SarcomereError
from sarcomere.dynamics.fidelity import REDUCED_FROM_N
from sarcomere.scenarios.explore import spec
from sarcomere.scenarios.explore.evaluate import evaluate_batch


def study(base: str, body: str = "", grid: str = 'load = ["20 g", "30 g"]'):
    text = f'[study]\nkind = "grid"\nbase = "{base}"\n[study.grid]\n{grid}\n'
    return spec.parse_study(text + textwrap.dedent(body), "/nonexistent/s.toml")


def test_a_study_on_a_short_auto_scene_runs_full_in_every_sample_and_says_so():
    auto = study("step-50g-auto")
    assert auto.fidelity.startswith("auto: full in every sample")
    assert f"below n = {REDUCED_FROM_N}" in auto.fidelity
    full = study("step-50g-auto", '[model]\nfidelity = "full"\n')
    assert full.fidelity == "full"
    got, ref = evaluate_batch(auto, [0, 1]), evaluate_batch(full, [0, 1])
    assert got.status.tolist() == [0, 0]
    for name, values in got.metrics.items():
        np.testing.assert_array_equal(values, ref.metrics[name])


def test_the_factor_n_of_an_auto_study_stays_where_the_rule_runs_full():
    with pytest.raises(
        SarcomereError, match=rf"{REDUCED_FROM_N}.*outside.*\[1, {REDUCED_FROM_N - 1}\]"
    ):
        study("step-50g-auto", grid=f"n = [3, {REDUCED_FROM_N}]")


def test_a_study_on_a_long_auto_scene_is_refused_in_terms_of_the_study_file():
    with pytest.raises(SarcomereError, match=r"set it in the study file, \[model\] fidelity"):
        study("step-50g-n30-auto")
    grouped = study("step-50g-n30-auto", '[model]\nfidelity = "grouped"\n')
    assert grouped.fidelity == "grouped"  # the base's auto tolerance went with its level
