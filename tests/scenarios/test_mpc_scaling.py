"""The RTI's scaling study (scenarios/studies/mpc_scaling.py): the variants run on the
same measurements, so their commands agree, and every timing is recorded."""

import pytest

from sarcomere.scenarios.studies import mpc_scaling


@pytest.mark.slow
def test_the_python_variants_run_side_by_side_with_equal_commands():
    keep = {k: v for k, v in mpc_scaling.VARIANTS.items() if k != "compiled"}
    row = mpc_scaling.at_length(1, 6, keep)
    assert row["n"] == 1 and row["nx"] == 8
    assert row["max_command_difference_Pa"] < 1e-3  # the same law, other solves
    assert "dense LU's flops" in row["python_banded"]["refused"]  # n = 1: no band pays
    for name in keep.keys() - {"python_banded"}:
        r = row[name]
        assert r["fallbacks"] == 0
        for key in ("step", "prepare", "feedback", "update"):
            assert r[f"{key}_cpu_median_ms"] > 0
        assert r["build_cpu_s"] > 0 and r["compiler_cpu_s"] == 0
    assert row["python_dense"]["ratio_to_dense"] == 1.0
