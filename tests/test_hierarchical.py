"""The hierarchical bootstrap (dqn_transfer.analysis.hierarchical) against values worked out by hand or from
the random-effects model's theory, and the power analysis of the first edition's pilot."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.stats
from rliable import metrics as rliable_metrics

from dqn_transfer.analysis.hierarchical import (
    bootstrap_p_value,
    failure_rate,
    hierarchical_bootstrap,
    holm,
    iqm_of_runs,
    maps_for_power,
    mean_difference,
    mean_of_runs,
    paired_mean_difference,
    paired_slope,
    power,
    probability_of_improvement,
    two_stage_variance,
    variance_components,
)
from dqn_transfer.analysis.stats import bootstrap_ci
from dqn_transfer.cli.power import main as power_main
from dqn_transfer.experiments.power import pilot_differences
from dqn_transfer.experiments.raw_data import read_data
from dqn_transfer.experiments.scoring import score

PILOT = Path(__file__).resolve().parents[1] / "results" / "v1" / "data" / "hypothesis.jsonl"


def simulated(rng: np.random.Generator, n_maps: int, n_seeds: int, sigma_map: float, sigma_run: float) -> np.ndarray:
    """``[maps, seeds]`` values of the normal random-effects model with mean 0."""
    return sigma_map * rng.standard_normal((n_maps, 1)) + sigma_run * rng.standard_normal((n_maps, n_seeds))


# ------------------------------------------------------------------------------------------- intervals


def test_with_map_effects_the_interval_is_wider_than_the_run_level_one_and_covers_the_population_mean():
    rng = np.random.default_rng(1)
    hierarchical_hits, naive_hits, ratios = 0, 0, []
    for _ in range(200):
        values = simulated(rng, n_maps=20, n_seeds=5, sigma_map=1.0, sigma_run=0.05)
        est = hierarchical_bootstrap(values, mean_of_runs, rng, n_resamples=1000)
        _, low, high = bootstrap_ci(values.ravel(), rng, n_resamples=1000)
        hierarchical_hits += est.low <= 0.0 <= est.high
        naive_hits += low <= 0.0 <= high
        ratios.append((est.high - est.low) / (high - low))
    # 20 maps: a percentile interval covers P(|t_19| < 1.96 sqrt(19/20)) = 0.93; the run-level one treats
    # 100 runs as independent, with a standard error sqrt(5) too small: P(|Z| < 1.96 / sqrt(5)) = 0.62
    assert 0.88 <= hierarchical_hits / 200 <= 0.98
    assert naive_hits / 200 < 0.75
    assert np.median(ratios) == pytest.approx(math.sqrt(5), rel=0.1)


def test_without_map_effects_it_is_the_run_level_interval_widened_by_the_second_stage():
    """No map-level variance: the two-stage bootstrap counts the run noise twice (once in the map means,
    once in the runs redrawn), so its variance is ((M - 1)/M + (S - 1)/S) / ((N - 1)/N) times the run-level
    bootstrap's, the same centre."""
    rng = np.random.default_rng(2)
    n_maps, n_seeds = 50, 4
    expected = math.sqrt(((n_maps - 1) / n_maps + (n_seeds - 1) / n_seeds) / (199 / 200))
    ratios, shifts = [], []
    for _ in range(20):
        values = simulated(rng, n_maps, n_seeds, sigma_map=0.0, sigma_run=1.0)
        est = hierarchical_bootstrap(values, mean_of_runs, rng, n_resamples=4000)
        _, low, high = bootstrap_ci(values.ravel(), rng, n_resamples=4000)
        ratios.append((est.high - est.low) / (high - low))
        shifts.append((est.high + est.low - high - low) / 2 / (high - low))
    assert np.mean(ratios) == pytest.approx(expected, rel=0.04)
    assert abs(np.mean(shifts)) < 0.02


def test_the_closed_form_variance_is_the_bootstraps():
    rng = np.random.default_rng(3)
    values = simulated(rng, n_maps=8, n_seeds=3, sigma_map=0.5, sigma_run=0.3)
    between = float(((values.mean(axis=1) - values.mean()) ** 2).sum())
    within = float(((values - values.mean(axis=1, keepdims=True)) ** 2).sum())
    est = hierarchical_bootstrap(values, mean_of_runs, rng, n_resamples=40_000, confidence=0.6827)
    assert (est.high - est.low) / 2 == pytest.approx(math.sqrt(two_stage_variance(between, within, 8, 3)), rel=0.03)


def test_maps_may_hold_unequal_runs_and_one_map_gives_no_interval():
    rng = np.random.default_rng(4)
    values = [[1.0, 2.0, 3.0], [10.0], [4.0, 5.0]]
    est = hierarchical_bootstrap(values, mean_of_runs, rng, n_resamples=2000)
    assert est.mean == pytest.approx(25.0 / 6.0) and est.n == 3
    assert 1.0 <= est.low < est.mean < est.high <= 10.0
    single = hierarchical_bootstrap([[1.0, 2.0]], mean_of_runs, rng)
    assert single.mean == 1.5 and not single.has_ci
    with pytest.raises(ValueError, match="finite"):
        hierarchical_bootstrap([[1.0, math.nan]], mean_of_runs, rng)


def test_iqm_of_rows_of_different_lengths_is_scipys_trimmed_mean():
    rng = np.random.default_rng(5)
    rows = rng.standard_normal((6, 11))
    lengths = [11, 10, 8, 7, 4, 1]
    padded = np.where(np.arange(11) < np.array(lengths)[:, None], rows, np.nan)
    expected = [scipy.stats.trim_mean(row[:k], 0.25) for row, k in zip(rows, lengths)]
    assert iqm_of_runs(padded) == pytest.approx(expected)
    est = hierarchical_bootstrap([[0.0, 1.0, 2.0, 100.0], [3.0, 4.0]], iqm_of_runs, rng, n_resamples=500)
    assert est.mean == pytest.approx(scipy.stats.trim_mean([0.0, 1.0, 2.0, 100.0, 3.0, 4.0], 0.25))


def test_failure_rate_is_the_fraction_of_runs_below_the_threshold():
    rng = np.random.default_rng(6)
    est = failure_rate([[0.0, 0.9], [0.0, 0.0], [1.0, 0.8]], threshold=0.5, rng=rng, n_resamples=2000)
    assert est.mean == pytest.approx(0.5)
    assert 0.0 <= est.low < 0.5 < est.high <= 1.0
    assert failure_rate([[0.6, 0.7], [0.9]], threshold=0.5, rng=rng).high == 0.0


# -------------------------------------------------------------------------------------- two conditions


def test_mean_difference_paired_by_seed_or_not():
    rng = np.random.default_rng(7)
    x = [[1.0, 2.0], [3.0, 5.0], [0.0, 1.0]]
    y = [[0.5, 1.0], [3.0, 4.0], [0.0, 0.0]]
    paired = mean_difference(x, y, rng, paired_seeds=True, n_resamples=2000)
    unpaired = mean_difference(x, y, rng, paired_seeds=False, n_resamples=2000)
    assert paired.estimate.mean == pytest.approx(3.5 / 6) and unpaired.estimate.mean == pytest.approx(3.5 / 6)
    # the seeds' shared noise cancels in a pair: 0.5, 1 | 0, 1 | 0, 1 vary less than the runs themselves
    assert paired.estimate.high - paired.estimate.low < unpaired.estimate.high - unpaired.estimate.low
    assert paired.estimate.n == 3 and 0.0 < paired.p_value <= 1.0
    direct = paired_mean_difference([np.subtract(a, b) for a, b in zip(x, y)], np.random.default_rng(8))
    again = mean_difference(x, y, np.random.default_rng(8), paired_seeds=True)
    assert (direct.estimate.low, direct.estimate.high) == (again.estimate.low, again.estimate.high)
    with pytest.raises(ValueError, match="same runs"):
        mean_difference([[1.0, 2.0]], [[1.0]], rng, paired_seeds=True)


def test_the_p_value_inverts_the_percentile_interval():
    resampled = np.arange(1, 100, dtype=np.float64)  # 99 values, none at or below 0
    assert bootstrap_p_value(resampled) == pytest.approx(2 / 100)
    assert bootstrap_p_value(resampled - 50.0) == 1.0
    assert bootstrap_p_value(resampled - 10.0) == pytest.approx(2 * 11 / 100)  # 1..10 at or below 10


def test_probability_of_improvement_by_hand():
    rng = np.random.default_rng(9)
    one_map = probability_of_improvement([[1.0, 2.0]], [[0.0, 3.0]], rng)  # 1>0, 1<3, 2>0, 2<3
    assert one_map.mean == 0.5 and not one_map.has_ci
    assert probability_of_improvement([[1.0, 1.0]], [[1.0, 0.0]], rng).mean == 0.75  # ties count one half
    two_maps = probability_of_improvement([[1.0, 2.0], [5.0]], [[0.0, 3.0], [4.0]], rng, n_resamples=2000)
    assert two_maps.mean == 0.75  # (0.5 + 1) / 2: averaged over maps, not pooled over pairs
    # a resample may draw the first map twice, its runs redrawn: x = [1, 1] against y = [3, 3] gives 0
    assert 0.0 <= two_maps.low <= 0.5 and two_maps.high == 1.0


def test_probability_of_improvement_is_rliables_point():
    rng = np.random.default_rng(10)
    x, y = rng.standard_normal((3, 5)) + 0.3, rng.standard_normal((3, 5))  # [runs, maps]
    est = probability_of_improvement(list(x.T), list(y.T), rng, paired_seeds=True, n_resamples=2000)
    assert est.mean == pytest.approx(float(rliable_metrics.probability_of_improvement(x, y)))
    assert est.low < est.mean < est.high


def test_holm_by_hand():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5, 0.01]) == pytest.approx([0.5, 0.02])
    assert holm([0.6, 0.7]) == pytest.approx([1.0, 1.0])  # 2 x 0.6 capped at 1, never below the one before


# ----------------------------------------------------------------------------------------------- power


def test_variance_components_recover_the_simulated_ones():
    rng = np.random.default_rng(11)
    values = simulated(rng, n_maps=400, n_seeds=5, sigma_map=0.3, sigma_run=0.1) + 2.0
    found = variance_components(values)
    assert (found.n_maps, found.n_runs) == (400, 2000)
    assert found.mean == pytest.approx(2.0, abs=0.05)
    assert found.sigma_map == pytest.approx(0.3, rel=0.1)
    assert found.sigma_run == pytest.approx(0.1, rel=0.05)
    unequal = [row[: 2 + i % 4] for i, row in enumerate(values)]
    assert variance_components(unequal).sigma_map == pytest.approx(0.3, rel=0.1)
    assert variance_components([[1.0, 2.0], [1.1, 1.9]]).sigma_map == 0.0  # equal map means: MSB < MSW, none


def test_power_grows_with_maps_and_is_the_level_without_an_effect():
    rng = np.random.default_rng(12)
    powers = [power(0.1, 0.2, 0.1, n_maps, 3, rng) for n_maps in (5, 10, 20, 40)]
    assert powers == sorted(powers) and powers[-1] > 0.8
    # 60 maps: the size of a normal interval at (M - 1)/M of the variance is P(|t_59| > 1.96 sqrt(59/60)) = 0.058
    assert power(0.0, 0.2, 0.01, 60, 3, rng) == pytest.approx(0.058, abs=0.01)
    assert power(0.0, 0.2, 0.01, 5, 3, rng) > 0.1  # few maps: too narrow


def test_simulated_power_rejects_as_often_as_the_bootstrap_interval():
    rng = np.random.default_rng(13)
    effect, sigma_map, sigma_run, n_maps, n_seeds = 0.15, 0.2, 0.1, 10, 3
    rejected = 0
    for _ in range(300):
        values = effect + simulated(rng, n_maps, n_seeds, sigma_map, sigma_run)
        est = paired_mean_difference(values, rng, n_resamples=1000).estimate
        rejected += est.low > 0.0 or est.high < 0.0
    assert rejected / 300 == pytest.approx(power(effect, sigma_map, sigma_run, n_maps, n_seeds, rng), abs=0.08)


def test_maps_for_power_is_the_fewest_reaching_the_target():
    rng = np.random.default_rng(14)
    needed = maps_for_power(0.1, 0.2, 0.1, 3, rng)
    assert needed is not None
    assert power(0.1, 0.2, 0.1, needed, 3, rng) >= 0.79
    assert power(0.1, 0.2, 0.1, needed - 2, 3, rng) < 0.8
    assert maps_for_power(1e-6, 1.0, 1.0, 2, rng, n_simulations=2000) is None


# ------------------------------------------------------------------------------------------ the pilot


def test_the_pilots_differences_are_the_first_editions():
    differences = pilot_differences(read_data(PILOT), "best", score)
    assert [d.size for d in differences] == [2] * 5
    assert np.concatenate(differences).mean() == pytest.approx(-0.0603, abs=5e-5)  # results/v1/REPORT.md


def test_a_pilot_that_cannot_be_read_is_one_error_line(tmp_path, capsys):
    assert power_main(["--pilot", str(tmp_path / "missing.jsonl")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot read") and err.count("\n") == 1
    (tmp_path / "empty.jsonl").write_text("")
    assert power_main(["--pilot", str(tmp_path / "empty.jsonl")]) == 2
    assert capsys.readouterr().err.startswith("error: the pilot has no sarsa cooperative runs")


def test_the_slope_over_team_size_of_paired_differences():
    # Constant differences 0.1, 0.3, 0.5 at m = 2, 4, 6: they rise 0.2 per 2 agents, slope 0.1 exactly, in every
    # resample.
    exact = {m: [np.full(3, d)] * 4 for m, d in ((2, 0.1), (4, 0.3), (6, 0.5))}
    result = paired_slope(exact, np.random.default_rng(0), n_resamples=200)
    assert (result.estimate.mean, result.estimate.low, result.estimate.high) == pytest.approx((0.1, 0.1, 0.1))
    assert result.p_value == pytest.approx(2 / 201) and result.estimate.n == 12
    # Unequal maps: the per-m means of the pooled runs are 0.2 (m = 2) and 0.0 (m = 3), so the slope is -0.2;
    # the maps differ, so the interval has width and holds the point.
    noisy = {2: [np.array([0.0, 0.2]), np.array([0.4])], 3: [np.array([-0.3, 0.3]), np.array([0.1, -0.1])]}
    result = paired_slope(noisy, np.random.default_rng(0))
    assert result.estimate.mean == pytest.approx((0.0 - (0.0 + 0.2 + 0.4) / 3) / (3 - 2))
    assert result.estimate.low < result.estimate.mean < result.estimate.high
    # One map at a size: no population to resample there, so no interval.
    assert math.isnan(paired_slope({2: [np.ones(2)], 3: [np.ones(2), np.ones(2)]}, np.random.default_rng(0)).p_value)
    with pytest.raises(ValueError, match="two sizes"):
        paired_slope({2: [np.ones(2)]}, np.random.default_rng(0))
