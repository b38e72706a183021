"""Differences judged against a smallest effect of interest (dqn_transfer.analysis.equivalence): the
tests against scipy's own t-tests, the outcome rule with Holm's adjustment worked out by hand, and the
power against a simulation of the random-effects model."""

import numpy as np
import pytest
import scipy.stats

from dqn_transfer.analysis.equivalence import (
    Contrast,
    Outcome,
    contrast,
    maps_for_power,
    normalised,
    outcomes,
    power,
)

DELTA = 0.03
# Paired differences of 4 maps x 2 seeds: map means 0.03, 0.04, 0.005, 0.055.
DIFFERENCES = [[0.02, 0.04], [0.05, 0.03], [0.01, 0.0], [0.06, 0.05]]


def test_a_contrast_is_scipys_t_tests_on_the_map_means():
    means = np.array([0.03, 0.04, 0.005, 0.055])
    c = contrast(DIFFERENCES, DELTA)
    assert c.mean == pytest.approx(means.mean()) and c.n_maps == 4
    assert c.p_difference == pytest.approx(scipy.stats.ttest_1samp(means, 0.0).pvalue)
    above = scipy.stats.ttest_1samp(means, -DELTA, alternative="greater").pvalue
    below = scipy.stats.ttest_1samp(means, DELTA, alternative="less").pvalue
    assert c.p_equivalence == pytest.approx(max(above, below))
    sem = scipy.stats.sem(means)
    assert (c.low, c.high) == pytest.approx(scipy.stats.t.interval(0.95, 3, loc=means.mean(), scale=sem))
    assert (c.low_tost, c.high_tost) == pytest.approx(scipy.stats.t.interval(0.90, 3, loc=means.mean(), scale=sem))


def test_equivalence_rejects_exactly_when_the_90_percent_interval_lies_inside_the_margins():
    rng = np.random.default_rng(0)
    seen = set()
    for _ in range(400):
        differences = rng.normal(rng.uniform(-0.04, 0.04), rng.uniform(0.005, 0.05), size=(rng.integers(3, 30), 3))
        c = contrast(list(differences), DELTA)
        inside = c.low_tost > -DELTA and c.high_tost < DELTA
        assert (c.p_equivalence < 0.05) == inside
        seen.add(inside)
    assert seen == {True, False}


def test_a_difference_the_same_on_every_map_is_known_exactly():
    assert contrast([[0.01, 0.01], [0.01]], DELTA).p_equivalence == 0.0  # inside the margins: equivalent
    same = contrast([[0.05], [0.05]], DELTA)
    assert (same.p_difference, same.p_equivalence, same.low, same.high) == (0.0, 1.0, 0.05, 0.05)
    with pytest.raises(ValueError, match="two maps"):
        contrast([[0.1, 0.2]], DELTA)


def made(mean: float, p_difference: float, p_equivalence: float) -> Contrast:
    return Contrast(mean, 0.0, 0.0, 0.0, 0.0, 40, p_difference, p_equivalence)


@pytest.mark.parametrize(
    ("mean", "p_difference", "p_equivalence", "outcome"),
    [
        (0.05, 0.01, 0.60, Outcome.better),
        (-0.05, 0.01, 0.60, Outcome.worse),
        (0.001, 0.50, 0.01, Outcome.equivalent),
        (0.01, 0.01, 0.01, Outcome.equivalent),  # there, but smaller than the SESOI: negligible
        (0.02, 0.30, 0.30, Outcome.inconclusive),
    ],
)
def test_the_outcome_of_a_lone_comparison(mean, p_difference, p_equivalence, outcome):
    assert outcomes([made(mean, p_difference, p_equivalence)]) == [outcome]


def test_holm_adjusts_each_test_within_the_family():
    # Holm on 0.02, 0.04, 0.5: 3 x 0.02 = 0.06, max(0.06, 2 x 0.04) = 0.08, 0.5: nothing below 0.05.
    family = [made(0.05, 0.02, 0.9), made(0.05, 0.04, 0.9), made(0.05, 0.5, 0.9)]
    assert outcomes(family) == [Outcome.inconclusive] * 3
    assert outcomes(family[:1]) == [Outcome.better]  # alone, 0.02 is below 0.05
    # Equivalence p-values 0.01, 0.02 -> 0.02, 0.02: both equivalent; 0.01, 0.03 -> 0.02, 0.03 also both.
    assert outcomes([made(0.0, 0.9, 0.01), made(0.0, 0.9, 0.02)]) == [Outcome.equivalent] * 2
    assert outcomes([made(0.0, 0.9, 0.01), made(0.0, 0.9, 0.03), made(0.0, 0.9, 0.04)]) == [
        Outcome.equivalent,  # 3 x 0.01 = 0.03
        Outcome.inconclusive,  # max(0.03, 2 x 0.03) = 0.06
        Outcome.inconclusive,  # max(0.06, 0.04)
    ]
    assert outcomes([]) == []


def test_power_is_the_share_of_simulated_studies_whose_t_test_rejects():
    delta, sigma_map, sigma_run, n_maps, n_seeds = 0.04, 0.05, 0.08, 10, 3
    rng = np.random.default_rng(1)
    studies = 20_000
    effects = delta + sigma_map * rng.standard_normal((studies, n_maps, 1))
    runs = effects + sigma_run * rng.standard_normal((studies, n_maps, n_seeds))
    p = scipy.stats.ttest_1samp(runs.mean(axis=2), 0.0, axis=1).pvalue
    simulated = float(np.mean(p < 0.05))
    assert power(delta, sigma_map, sigma_run, n_maps, n_seeds) == pytest.approx(simulated, abs=0.012)


def test_power_stays_a_probability_where_the_lower_tail_underflows():
    # The third edition's pilot of L2 (sigma_map 0, sigma_run 0.0642, 85 maps, Holm's 0.05 / 4): the test's
    # shift is 7.46 standard errors, so the power is the normal approximation's 1 - 4.6e-7 within 1e-6; scipy's
    # noncentral t cdf of the lower tail there is nan, which it once returned.
    value = power(0.03, 0.0, 0.0642, 85, 3, 0.05 / 4)
    assert value == pytest.approx(scipy.stats.norm.sf(scipy.stats.t.ppf(1 - 0.05 / 8, 84) - 7.462), abs=1e-6)
    assert 0.999 < value <= 1.0


def test_maps_for_power_are_the_fewest_that_reach_it():
    n = maps_for_power(0.03, 0.04, 0.06, n_seeds=3, alpha=0.05 / 4)
    assert power(0.03, 0.04, 0.06, n, 3, 0.05 / 4) >= 0.8 > power(0.03, 0.04, 0.06, n - 1, 3, 0.05 / 4)


def test_normalised_puts_the_random_team_at_0_and_the_oracle_at_1():
    assert normalised(np.array([-20.0, 90.0, 200.0]), -20.0, 200.0).tolist() == [0.0, 0.5, 1.0]
