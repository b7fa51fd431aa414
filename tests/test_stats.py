"""Intervals over seeds and paired tests by seed (rosmeery_jax.results.statistics), by hand."""

from __future__ import annotations

import numpy as np
import pytest

from rosmeery_jax.results import statistics


def test_the_sign_flip_test_is_exact_on_small_samples():
    # d = (3, 1, -2): the 8 sign patterns sum to 6, 4, 2, 0, 0, -2, -4, -6; |sum| >= |3 + 1 - 2| = 2 in 6
    assert statistics.paired([0, 0, 0], [3, 1, -2]).p == pytest.approx(6 / 8)
    assert statistics.paired([0, 0, 0], [3, 1, 2]).p == pytest.approx(2 / 8)  # only all + and all - as extreme
    assert statistics.paired([0.5] * 5, [0.6, 0.61, 0.62, 0.63, 0.64]).p == pytest.approx(2 / 2**5)
    assert statistics.paired([1, 2, 3, 4], [1, 2, 3, 4]).p == 1.0  # no difference at all


def test_five_seeds_can_never_show_a_difference_and_six_can():
    assert statistics.seeds_needed() == 6
    far = np.arange(5.0)
    assert not statistics.paired(far, far + 10).significant  # p = 0.0625 however large the gap
    assert statistics.paired(np.arange(6.0), np.arange(6.0) + 10).significant


def test_the_interval_holds_the_mean_and_is_reproducible():
    v = [0.52, 0.61, 0.55, 0.70, 0.49, 0.58, 0.66, 0.53]
    a, b = statistics.interval(v), statistics.interval(v)
    assert a == b and a.low < a.mean < a.high and a.mean == pytest.approx(np.mean(v))
    assert a.high - a.low < np.ptp(v)
    assert statistics.interval([0.25, 0.25, 0.25]) == (0.25, 0.25, 0.25)  # no spread, no interval
    two = statistics.interval([0.2, 0.4])
    assert two.mean == pytest.approx(0.3) and np.isnan(two.low) and np.isnan(two.high)  # too few seeds
    wide = statistics.interval(np.r_[v, 0.1, 0.95])
    assert wide.high - wide.low > a.high - a.low  # more spread, a wider interval


def test_a_paired_difference_of_under_three_seeds_has_no_interval_as_a_mean_has_none():
    one = statistics.paired([0.5], [0.6])  # a zero-width interval [+0.1, +0.1] before
    assert one.diff.mean == pytest.approx(0.1) and np.isnan(one.diff.low) and np.isnan(one.diff.high)
    assert one.p == 1.0 and not one.significant
    assert np.isnan(statistics.paired([0.5, 0.5], [0.6, 0.6]).diff.low)  # two equal differences: still too few
    assert statistics.paired([0.5] * 3, [0.6] * 3).diff == pytest.approx((0.1, 0.1, 0.1))  # three: the mean itself


def test_an_interval_prints_its_bounds_or_why_it_has_none():
    assert statistics.Interval(0.5, 0.41, 0.6).bounds() == "[0.41, 0.60]"
    assert statistics.Interval(0.1, -0.02, 0.25).bounds("+.3f") == "[-0.020, +0.250]"
    assert statistics.interval([0.4, 0.5]).bounds() == "[< 3 seeds]"
    assert statistics.interval([0.4, float("nan"), 0.5]).bounds() == "[NaN values]"


def test_a_paired_difference_is_signed_b_minus_a():
    r = statistics.paired([0.5, 0.6, 0.55, 0.7, 0.52, 0.5], [0.6, 0.71, 0.65, 0.8, 0.62, 0.58])
    assert r.diff.mean == pytest.approx(0.09833, abs=1e-4) and r.diff.low > 0 and r.significant and r.seeds == 6


def test_the_effect_size_is_the_mean_difference_in_standard_deviations_of_the_differences():
    # d = (1, 3): mean 2, SD (ddof 1) sqrt(((1 - 2)^2 + (3 - 2)^2) / 1) = sqrt(2)
    r = statistics.paired([0, 0], [1, 3])
    assert r.sd == pytest.approx(np.sqrt(2)) and r.in_sds == pytest.approx(2 / np.sqrt(2))
    assert statistics.paired([0, 0, 0], [-3, -1, -2]).in_sds == pytest.approx(-2.0)  # behind: negative
    assert np.isnan(statistics.paired([0, 0], [1, 1]).in_sds)  # every seed the same difference: no spread
    assert np.isnan(statistics.paired([0], [1]).sd)  # one seed: no spread to measure


def test_tied_with_best_bolds_the_best_and_what_a_paired_test_cannot_tell_from_it():
    import pandas as pd

    base = np.array([0.50, 0.60, 0.55, 0.70, 0.52, 0.58])
    table = pd.DataFrame({"a": base + 0.10,  # the best
                          "b": base + 0.10 + [0.01, -0.01, 0.02, -0.02, 0.01, -0.01],  # mixed signs: a tie
                          "c": base})  # behind the best in every seed (p = 2 / 2^6)
    assert statistics.tied_with_best(table) == {"a": True, "b": True, "c": False}
    assert statistics.bold_cells(table, ["c", "a"], lambda p, ci: f"{p} {ci.mean:.3f}") == ["c 0.575", "**a 0.675**"]


def test_a_nan_seed_is_no_finding_and_unpaired_values_are_refused():
    """A NaN seed gave p = 0.0, a 'significant' difference; values of different lengths
    (one broadcast over the other) or a table are not seeds."""
    r = statistics.paired([0.1, 0.2, 0.3], [0.5, np.nan, 0.7])
    assert np.isnan(r.p) and np.isnan(r.diff.mean) and r.seeds == 3
    i = statistics.interval([0.1, np.nan, 0.3, 0.4])
    assert np.isnan(i.mean) and np.isnan(i.low) and np.isnan(i.high)
    with pytest.raises(ValueError, match="paired: 3 and 1 values"):
        statistics.paired([0.1, 0.2, 0.3], [0.5])
    with pytest.raises(ValueError, match=r"shape \(2, 3\): one per seed"):
        statistics.interval(np.ones((2, 3)))
