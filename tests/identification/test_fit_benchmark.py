"""The fit benchmark's bookkeeping (benchmarks/fit.py) on made-up records: the baseline's
time to a cost, the replicate data in the problem's row order, interval containment and
the coverage rates."""

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.fit import contains, coverage_rates, replicate_vector, time_to_reach


def test_time_to_reach_is_the_first_evaluation_at_or_below_the_cost():
    trace = [(0.1, 0.2, 9.0), (0.3, 0.5, 4.0), (0.6, 0.9, 2.0), (0.8, 1.1, 1.5)]
    assert time_to_reach(trace, 4.0) == (0.3, 0.5)
    assert time_to_reach(trace, 1.9) == (0.8, 1.1)
    assert time_to_reach(trace, 1.0) is None


def test_replicate_vector_follows_the_rows_samples_and_static_levels():
    rng = np.random.default_rng(3)
    draws = {
        "step": {"len": rng.normal(size=6), "p": rng.normal(size=6)},
        "curve": {"len": rng.normal(size=4)},
    }
    samples = rng.permutation(6)[:4].tolist()
    rows = SimpleNamespace(
        experiment=["step"] * 4 + ["step"] * 2 + ["curve#3:len", "curve#1:len"],
        signal=["len"] * 4 + ["p"] * 2 + ["len", "len"],
        sample=samples + [5, 0, -1, -1],
    )
    got = replicate_vector(rows, draws)
    want = [draws["step"]["len"][s] for s in samples]
    want += [draws["step"]["p"][5], draws["step"]["p"][0]]
    want += [draws["curve"]["len"][2], draws["curve"]["len"][0]]
    np.testing.assert_array_equal(got, want)


def test_contains_with_open_ends_up_to_the_bounds():
    assert contains((1.0, 2.0), 1.5)
    assert not contains((1.0, 2.0), 2.5)
    assert contains((None, 2.0), 0.5, (0.1, 10.0))
    assert not contains((None, 2.0), 0.05, (0.1, 10.0))
    assert contains((1.0, None), 9.0, (0.1, 10.0))


def test_coverage_rates_count_converged_replicates_only():
    def rec(lo, status="converged", prof=None):
        r = {
            "status": status,
            "names": ["a", "b"],
            "truth": [1.0, 5.0],
            "fisher": [[lo, 1.5], [4.0, 6.0]],
            "verdict": ["identifiable", "identifiable"],
        }
        if prof is not None:
            r["profile"] = {"a": {"interval": prof, "open_to": [0.1, 10.0]}}
        return r

    results = [rec(0.5, prof=[0.9, None]), rec(1.2, prof=[1.1, 2.0]), rec(0.8), rec(0.5, "failed")]
    out = coverage_rates(results)
    assert out["a"]["fisher"]["hits"] == "2/3"
    assert out["b"]["fisher"]["hits"] == "3/3"
    assert out["a"]["profile"]["hits"] == "1/2"
    assert out["a"]["profile_open"] == 1
    assert out["a"]["verdicts"] == {"identifiable": 3}
    low, high = out["a"]["fisher"]["rate_ci95"]
    assert low < 2 / 3 < high
    assert low == pytest.approx(0.0943, abs=1e-3)  # Clopper-Pearson, 2 of 3


def test_coverage_rate_interval_is_clopper_pearson():
    """By its definition: at the lower end P(X >= k) = 2.5 %, at the upper P(X <= k) = 2.5 %."""
    from scipy.special import bdtr

    names, truth = ["a"], [0.0]
    for k, n in ((0, 5), (5, 5), (181, 200), (7, 20)):
        results = [
            {
                "status": "converged",
                "names": names,
                "truth": truth,
                "fisher": [[-1.0, 1.0] if i < k else [1.0, 2.0]],
                "verdict": ["identifiable"],
            }
            for i in range(n)
        ]
        low, high = coverage_rates(results)["a"]["fisher"]["rate_ci95"]
        assert low < k / n < high or (k == 0 and low == 0) or (k == n and high == 1)
        if k > 0:
            assert 1 - bdtr(k - 1, n, low) == pytest.approx(0.025, abs=1e-9)
        if k < n:
            assert bdtr(k, n, high) == pytest.approx(0.025, abs=1e-9)


def test_success_is_within_one_chi2_of_the_family_best():
    from benchmarks.fit import success_summary

    inf = float("inf")
    runs = {
        "ms": [
            {"cost": 10.0, "cpu_s": 1.0, "status": "converged"},
            {"cost": inf, "cpu_s": 9.0, "status": "stuck"},
        ],
        "ss": [
            {"cost": 10.4, "cpu_s": 2.0, "status": "converged"},
            {"cost": 10.6, "cpu_s": 4.0, "status": "converged"},
        ],
        "lsq": [
            {"cost": 20.0, "cpu_s": 3.0, "status": 2},
            {"cost": 21.0, "cpu_s": 5.0, "status": 3},
        ],
    }
    best, out = success_summary(runs, reference_cost=19.8)
    assert best == {"engine": 10.0, "scipy": 19.8}  # each family its own best
    assert out["ms"]["success"] == "1/2" and out["ms"]["failures"] == {"1": [inf, "stuck"]}
    assert out["ss"]["success"] == "1/2"  # 10.6: chi-squared 1.2 above the best
    assert out["lsq"]["success"] == "1/2" and out["lsq"]["cpu_median_s"] == 4.0


def test_noisy_input_data_touches_only_the_time_series_pressure(tmp_path):
    """The records of the noisy-input benchmark: the step and staircase pressure columns
    carry the stated noise (never below 0), everything else is the packaged file."""
    from importlib import resources

    from benchmarks.fit import noisy_input_data

    noisy_input_data(tmp_path, noise_kpa=0.2, seed=1)
    root = resources.files("sarcomere.scenarios.fits") / "data"
    for f in sorted(p for p in root.iterdir() if p.name.endswith(".csv")):
        old, new = f.read_text().splitlines(), (tmp_path / f.name).read_text().splitlines()
        first = next(i for i, ln in enumerate(old) if ln[:1].isdigit())
        assert new[:first] == old[:first] and len(new) == len(old)
        col = (
            old[first - 1]
            .split(",")
            .index(next(h for h in old[first - 1].split(",") if h.startswith("pressure")))
        )
        a = np.array([[float(x) for x in ln.split(",")] for ln in old[first:]])
        b = np.array([[float(x) for x in ln.split(",")] for ln in new[first:]])
        np.testing.assert_array_equal(np.delete(a, col, axis=1), np.delete(b, col, axis=1))
        if old[first - 1].startswith("time"):  # a time series: pressure [kPa] noisy
            assert np.all(b[:, col] >= 0)
            assert np.std(b[:, col] - a[:, col]) == pytest.approx(0.2, rel=0.2)
        else:
            np.testing.assert_array_equal(a, b)
