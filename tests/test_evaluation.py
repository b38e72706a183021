"""dqn_transfer.analysis: transfer metrics and bootstrap CIs on hand-made curves and run directories
(values worked by hand), and the comparison command line."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rliable import library as rly
from rliable import metrics as rlm

from dqn_transfer.analysis.compare import compare_runs, format_table
from dqn_transfer.analysis.runs import EvaluationError, learning_curve, read_metrics
from dqn_transfer.analysis.stats import (
    bootstrap_ci,
    curve_band,
    improvement_probability,
    iqm,
    mean_intervals,
    performance_profile,
)
from dqn_transfer.analysis.transfer_metrics import (
    asymptotic_performance,
    jumpstart,
    mean_curve,
    time_to_threshold,
    total_reward,
    transfer_ratio,
)
from dqn_transfer.cli import compare
from dqn_transfer.storage.run_dir import RunDir

REPO = Path(__file__).resolve().parents[1]


def curve(steps, values):
    return np.array(steps, dtype=float), np.array(values, dtype=float)


def make_run(path: Path, returns: list[float], seed: int | None = None, step_every: int = 10) -> Path:
    path.mkdir(parents=True)
    lines = [json.dumps({"step": i * step_every, "team_return": r, "success_rate": 0.5}) for i, r in enumerate(returns)]
    files = RunDir(path)
    files.metrics.write_text("\n".join(lines) + "\n")
    if seed is not None:
        files.hydra_dir.mkdir()
        files.config.write_text(f"seed: {seed}\ntotal_steps: 20\n")
    return path


# ------------------------------------------------------------------ metrics on curves


def test_total_reward_is_the_trapezoid_area():
    # 10 * (0 + 5) / 2 + 10 * (5 + 10) / 2 = 25 + 75 = 100
    assert total_reward(curve([0, 10, 20], [0, 5, 10])) == 100.0
    # 10 * (-30 - 10) / 2 + 10 * (-10 + 0) / 2 = -200 - 50 = -250
    assert total_reward(curve([0, 10, 20], [-30, -10, 0])) == -250.0
    assert total_reward(curve([5], [3])) == 0.0


def test_asymptotic_performance_averages_the_tail():
    values = list(range(10))
    assert asymptotic_performance(curve(range(10), values)) == 9.0  # ceil(0.1 * 10) = 1 -> 9
    assert asymptotic_performance(curve(range(10), values), 0.3) == 8.0  # (7 + 8 + 9) / 3
    # 0.1 * 30 is 3.0000000000000004 in floating point; still the last 3: (27 + 28 + 29) / 3 = 28
    assert asymptotic_performance(curve(range(30), range(30))) == 28.0
    assert asymptotic_performance(curve([0, 10, 20], [1, 2, 3]), 1.0) == 2.0  # (1 + 2 + 3) / 3


def test_jumpstart_compares_the_first_common_evaluation():
    # -20 - (-50) = 30
    assert jumpstart(curve([0, 10, 20], [-20, -10, 0]), curve([0, 10, 20], [-50, -30, -10])) == 30.0
    # first common step is 10: 5 - 2 = 3
    assert jumpstart(curve([10, 20], [5, 6]), curve([0, 10, 20], [-1, 2, 3])) == 3.0
    with pytest.raises(ValueError, match="share no evaluation step"):
        jumpstart(curve([5, 15], [0, 0]), curve([0, 10], [0, 0]))


def test_time_to_threshold_is_the_first_step_at_or_above():
    c = curve([0, 10, 20, 30], [-5, 0, 3, 1])
    assert time_to_threshold(c, 2.0) == 20.0
    assert time_to_threshold(c, 0.0) == 10.0  # inclusive
    assert math.isnan(time_to_threshold(c, 4.0))


def test_transfer_ratio_uses_areas_above_the_common_floor():
    transfer = curve([0, 10, 20], [-40, -20, -20])
    baseline = curve([0, 10, 20], [-60, -40, -20])
    # floor = -60. transfer above it: [20, 40, 40] -> 10*(20+40)/2 + 10*(40+40)/2 = 300 + 400 = 700
    # baseline above it: [0, 20, 40] -> 10*(0+20)/2 + 10*(20+40)/2 = 100 + 300 = 400
    # ratio = (700 - 400) / 400 = 0.75
    assert transfer_ratio(transfer, baseline) == pytest.approx(0.75)

    # invariant to shifting and scaling every return (e.g. a different step cost offset)
    def rescaled(c):
        return c[0], 2.0 * c[1] + 1000.0

    assert transfer_ratio(rescaled(transfer), rescaled(baseline)) == pytest.approx(0.75)
    assert transfer_ratio(baseline, baseline) == 0.0
    assert transfer_ratio(baseline, transfer) < 0.0


def test_transfer_ratio_on_partly_overlapping_grids():
    # transfer v = s on [0, 20]; baseline v = s - 10 on [10, 30]; both cover [10, 20]:
    # transfer 10 -> 20, baseline 0 -> 10, floor 0
    # areas 10*(10+20)/2 = 150 and 10*(0+10)/2 = 50 -> (150 - 50) / 50 = 2
    assert transfer_ratio(curve([0, 20], [0, 20]), curve([10, 30], [0, 20])) == pytest.approx(2.0)
    # baseline flat at the floor: area 0 -> inf; both flat and equal: 0 / 0 -> nan
    assert transfer_ratio(curve([0, 20], [0, 20]), curve([10, 30], [0, 0])) == math.inf
    assert math.isnan(transfer_ratio(curve([0, 10], [-5, -5]), curve([0, 10], [-5, -5])))
    assert math.isnan(transfer_ratio(curve([0, 10], [1, 2]), curve([20, 30], [1, 2])))  # no overlap


def test_curves_are_validated():
    with pytest.raises(ValueError, match="strictly increasing"):
        total_reward(curve([0, 10, 10], [1, 2, 3]))
    with pytest.raises(ValueError, match="equal length"):
        total_reward(curve([0, 10], [1]))


# ------------------------------------------------------------------ bootstrap


def test_bootstrap_ci_constant_data_has_zero_width():
    assert bootstrap_ci([3.0, 3.0, 3.0, 3.0], np.random.default_rng(0)) == (3.0, 3.0, 3.0)


def test_bootstrap_ci_on_two_values():
    # resampled means of [0, 1]: 0 w.p. 1/4, 0.5 w.p. 1/2, 1 w.p. 1/4, so the 2.5% and 97.5%
    # quantiles are 0 and 1, while the 30% and 70% quantiles (confidence 0.4) are both 0.5
    assert bootstrap_ci([0.0, 1.0], np.random.default_rng(0)) == (0.5, 0.0, 1.0)
    assert bootstrap_ci([0.0, 1.0], np.random.default_rng(0), confidence=0.4) == (0.5, 0.5, 0.5)


def test_bootstrap_ci_contains_the_mean_and_is_reproducible():
    values = [1.0, 2.0, 3.0, 4.0, 5.0]
    mean, low, high = bootstrap_ci(values, np.random.default_rng(1))
    assert mean == 3.0 and 1.0 <= low < 3.0 < high <= 5.0
    assert bootstrap_ci(values, np.random.default_rng(1)) == (mean, low, high)
    _, low_50, high_50 = bootstrap_ci(values, np.random.default_rng(1), confidence=0.5)
    assert low <= low_50 < high_50 <= high


def test_bootstrap_ci_single_value_has_no_interval():
    mean, low, high = bootstrap_ci([7.0], np.random.default_rng(0))
    assert mean == 7.0 and math.isnan(low) and math.isnan(high)
    with pytest.raises(ValueError):
        bootstrap_ci([], np.random.default_rng(0))


def test_curve_band_over_the_common_steps():
    curves = [curve([0, 10, 20], [0, 2, 4]), curve([0, 10], [2, 6])]
    steps, mean, low, high = curve_band(curves, np.random.default_rng(0))
    np.testing.assert_array_equal(steps, [0.0, 10.0])
    np.testing.assert_array_equal(mean, [1.0, 4.0])  # the same mean as mean_curve
    assert np.all(low <= mean) and np.all(mean <= high) and low[0] >= 0.0 and high[0] <= 2.0
    _, mean, low, high = curve_band(curves[:1], np.random.default_rng(0))  # one run: the band is the curve
    np.testing.assert_array_equal(low, mean)
    np.testing.assert_array_equal(high, mean)
    with pytest.raises(ValueError, match="share no evaluation step"):
        curve_band([curve([0], [1]), curve([5], [1])], np.random.default_rng(0))


# ------------------------------------------------------------------ run directories


def test_read_metrics_and_learning_curve(tmp_path: Path):
    run = tmp_path / "run"
    run.mkdir()
    RunDir(run).metrics.write_text(
        '{"step": 20, "team_return": -4.0}\n'
        '{"step": 10, "team_return": -9.0}\n'
        "\n"
        '{"step": 20, "team_return": -3.0, "success_rate": 1.0}\n'  # resumed run re-evaluated step 20
        '{"step": 30, "team_ret'  # killed mid-write
    )
    with pytest.warns(UserWarning, match="incomplete last line 5"):
        assert len(read_metrics(run)) == 3
    with pytest.warns(UserWarning):
        steps, values = learning_curve(run)
    np.testing.assert_array_equal(steps, [10.0, 20.0])
    np.testing.assert_array_equal(values, [-9.0, -3.0])  # the later record of step 20 wins
    with pytest.warns(UserWarning), pytest.raises(EvaluationError, match="available: success_rate, team_return"):
        learning_curve(run, "episodic_length")


def test_read_metrics_errors(tmp_path: Path):
    with pytest.raises(EvaluationError, match="no such run directory"):
        read_metrics(tmp_path / "missing")
    with pytest.raises(EvaluationError, match="metrics.jsonl: missing"):
        read_metrics(tmp_path)
    RunDir(tmp_path).metrics.write_text('{"step": 0}\nnot json\n{"step": 10}\n')
    with pytest.raises(EvaluationError, match="line 2 is not valid JSON"):
        read_metrics(tmp_path)


def test_mean_curve_uses_the_common_steps():
    steps, values = mean_curve([curve([0, 10, 20], [0, 2, 4]), curve([0, 10], [2, 6])])
    np.testing.assert_array_equal(steps, [0.0, 10.0])
    np.testing.assert_array_equal(values, [1.0, 4.0])  # (0 + 2) / 2, (2 + 6) / 2


@pytest.fixture
def runs(tmp_path: Path) -> tuple[list[Path], list[Path]]:
    """Evaluations at steps 0, 10, 20; transfer given in reverse seed order to exercise pairing."""
    baseline = [make_run(tmp_path / "b0", [-60, -40, -20], seed=0), make_run(tmp_path / "b1", [-40, -20, 0], seed=1)]
    transfer = [make_run(tmp_path / "t1", [-10, 0, 10], seed=1), make_run(tmp_path / "t0", [-30, -10, 0], seed=0)]
    return transfer, baseline


def test_compare_runs_by_hand(runs):
    transfer, baseline = runs
    r = compare_runs(transfer, baseline, threshold=-5.0)
    # jumpstart paired by seed at step 0: t0 -30 - b0 -60 = 30, t1 -10 - b1 -40 = 30
    assert (r["jumpstart"]["mean"], r["jumpstart"]["n"]) == (30.0, 2)
    # mean baseline curve: [-50, -30, -10]
    # transfer_ratio vs mean baseline, floor -50; baseline above it [0, 20, 40] -> area 100 + 300 = 400
    # t0 above floor [20, 40, 50] -> 300 + 450 = 750 -> 350/400 = 0.875
    # t1 above floor [40, 50, 60] -> 450 + 550 = 1000 -> 600/400 = 1.5;  mean (0.875 + 1.5) / 2 = 1.1875
    assert r["transfer_ratio"]["mean"] == pytest.approx(1.1875)
    # asymptotic (last of 3 evaluations): transfer [10, 0] -> 5, baseline [-20, 0] -> -10,
    # differences by seed: t0 - b0 = 0 - (-20) = 20, t1 - b1 = 10 - 0 = 10 -> 15, CI [10, 20]
    assert r["asymptotic_performance/transfer"]["mean"] == 5.0
    assert r["asymptotic_performance/baseline"]["mean"] == -10.0
    assert r["asymptotic_performance/difference"] == {"mean": 15.0, "low": 10.0, "high": 20.0, "n": 2}
    # total reward: t0 -200 - 50 = -250, t1 -50 + 50 = 0 -> -125; b0 -500 - 300 = -800, b1 -300 - 100 = -400
    # -> -600; differences 550 and 400 -> 475
    assert r["total_reward/transfer"]["mean"] == -125.0
    assert r["total_reward/baseline"]["mean"] == -600.0
    assert r["total_reward/difference"]["mean"] == 475.0
    # threshold -5: t0 at step 20, t1 at step 10 -> 15; b0 never (nan, left out), b1 at 20 -> n = 1
    # difference only where both reach it: t1 - b1 = 10 - 20 = -10 (pairing t1 with b0 would give none)
    assert r["time_to_threshold/transfer"]["mean"] == 15.0
    baseline_ttt = r["time_to_threshold/baseline"]
    assert (baseline_ttt["mean"], baseline_ttt["n"]) == (20.0, 1) and math.isnan(baseline_ttt["low"])
    assert r["time_to_threshold/difference"]["mean"] == -10.0
    assert r["time_to_threshold/difference"]["n"] == 1
    # every run counts for the probabilities: final values t [0, 10] vs b [-20, 0] -> pairs 0 > -20, 0 = 0
    # (half), 10 > -20, 10 > 0 -> 3.5 / 4; times t [20, 10] vs b [never, 20] -> 20 < never, 20 = 20 (half),
    # 10 < never, 10 < 20 -> 3.5 / 4. The IQM of two values trims none: their mean.
    assert r["asymptotic_performance/P(transfer > baseline)"]["mean"] == 0.875
    assert r["time_to_threshold/P(transfer sooner)"]["mean"] == 0.875
    assert r["asymptotic_performance/transfer_iqm"]["mean"] == 5.0
    assert r["asymptotic_performance/baseline_iqm"]["mean"] == -10.0


def test_compare_runs_at_equal_total_steps_counts_the_transfer_runs_earlier_steps(runs):
    transfer, baseline = runs
    r = compare_runs(transfer, baseline, threshold=-5.0, transfer_offset=10)
    # transfer evaluations now at total steps 10, 20, 30; the mean baseline [-50, -30, -10] at 0, 10, 20.
    # jumpstart at the transfer runs' first evaluation (10), paired by seed: t0 -30 - b0 -40 = 10,
    # t1 -10 - b1 -20 = 10
    assert r["jumpstart"]["mean"] == 10.0
    # threshold -5 reached at own steps 20 (t0) and 10 (t1): total steps 30 and 20
    assert r["time_to_threshold/transfer"]["mean"] == 25.0
    assert r["asymptotic_performance/transfer"]["mean"] == 5.0  # the end of each run, as before
    # areas over the span every run covers, steps 10..20: t0 [-30, -10] -> -200, t1 [-10, 0] -> -50;
    # b0 [-40, -20] -> -300, b1 [-20, 0] -> -100; paired by seed: 100 and 50
    assert r["total_reward/transfer"]["mean"] == -125.0 and r["total_reward/baseline"]["mean"] == -200.0
    assert r["total_reward/difference"]["mean"] == 75.0
    with pytest.raises(ValueError, match="transfer offset"):
        compare_runs(transfer, baseline, transfer_offset=-1)


def test_compare_runs_without_threshold_and_with_unequal_counts(runs):
    transfer, baseline = runs
    with pytest.warns(UserWarning, match="2 transfer vs 1 baseline"):
        r = compare_runs(transfer, baseline[:1])
    assert "time_to_threshold/transfer" not in r
    # only b0 is left, so the mean baseline is b0; t0 pairs with b0: asymptotic 0 - (-20) = 20
    assert r["asymptotic_performance/difference"]["n"] == 1
    assert r["asymptotic_performance/difference"]["mean"] == 20.0


def test_format_table():
    results = {
        "jumpstart": {"mean": 30.0, "low": 20.0, "high": 40.0, "n": 2},
        "transfer_ratio": {"mean": 0.5, "low": 0.5, "high": 0.5, "n": 3},
        "time_to_threshold/baseline": {"mean": 20.0, "low": math.nan, "high": math.nan, "n": 1},
    }
    assert format_table(results) == (
        "| metric | mean | 95% CI | n |\n"
        "|---|---:|---:|---:|\n"
        "| jumpstart | 30 | [20, 40] | 2 |\n"
        "| transfer_ratio | 0.5 | no spread | 3 |\n"
        "| time_to_threshold/baseline | 20 | n/a | 1 |"
    )


def test_cli_prints_the_table(runs, capsys):
    transfer, baseline = runs
    args = ["--transfer", *map(str, transfer), "--baseline", *map(str, baseline), "--threshold", "-5"]
    assert compare.main(args) == 0
    out = capsys.readouterr().out
    assert out.startswith("| metric | mean | 95% CI | n |")
    assert "| jumpstart | 30 | no spread | 2 |" in out  # paired by seed, both pairs differ by 30


def test_cli_missing_dir_is_one_error_line(tmp_path: Path):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "dqn_transfer.cli.compare",
            "--transfer",
            str(tmp_path / "nope"),
            "--baseline",
            str(tmp_path),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.splitlines() == [f"error: {tmp_path / 'nope'}: no such directory"]


def _not_yet_evaluated(path: Path) -> Path:
    """A run directory whose run has started but not evaluated: its config, no evaluation."""
    files = RunDir(path)
    files.hydra_dir.mkdir(parents=True)
    files.config.write_text("seed: 7\ntotal_steps: 20\n")
    return path


def test_cli_skips_what_is_not_a_run_and_says_why(runs, tmp_path: Path, capsys):
    transfer, baseline = runs
    started = _not_yet_evaluated(tmp_path / "started")  # a job still before its first evaluation
    empty = _not_yet_evaluated(tmp_path / "empty")
    RunDir(empty).metrics.write_text("")
    args = [
        "--transfer",
        *map(str, transfer),
        str(started),
        "--baseline",
        *map(str, baseline),
        str(empty),
        "--threshold",
        "-5",
    ]
    assert compare.main(args) == 0
    captured = capsys.readouterr()
    # The same numbers as without the two directories (test_compare_runs_by_hand): nothing mixed in.
    assert "| jumpstart | 30 | no spread | 2 |" in captured.out
    assert "| total_reward/difference | 475 |" in captured.out
    assert captured.err.splitlines() == [
        f"skipped {started}: no metrics.jsonl (the run has not evaluated)",
        f"skipped {empty}: metrics.jsonl holds no evaluations yet",
    ]


def test_cli_with_no_usable_run_on_one_side_is_an_error(runs, tmp_path: Path, capsys):
    _, baseline = runs
    started, empty = _not_yet_evaluated(tmp_path / "started"), _not_yet_evaluated(tmp_path / "empty")
    RunDir(empty).metrics.write_text("")
    assert compare.main(["--transfer", str(started), str(empty), "--baseline", *map(str, baseline)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"skipped {started}: no metrics.jsonl (the run has not evaluated)",
        f"skipped {empty}: metrics.jsonl holds no evaluations yet",
        "error: no usable transfer run directory among the 2 given (2 skipped)",
    ]


# ------------------------------------------------------------------ rliable's aggregates, known answers


def test_a_clear_win_a_tie_and_an_overlap_have_the_probability_of_improvement_worked_by_hand():
    rng = np.random.default_rng(0)
    win = improvement_probability(np.arange(10, 20), np.arange(10), rng)
    assert (win.mean, win.low, win.high, win.n) == (1.0, 1.0, 1.0, 10)  # every resample is a win too
    tie = improvement_probability(np.arange(10), np.arange(10), rng)
    assert tie.mean == 0.5 and tie.low < 0.5 < tie.high
    # x 0..9 against y 5..14: x > y in 1 + 2 + 3 + 4 = 10 pairs, x = y in 5, of 100 -> (10 + 5 / 2) / 100
    overlap = improvement_probability(np.arange(10), np.arange(5, 15), rng)
    assert overlap.mean == pytest.approx(0.125) and overlap.high < 0.5


def test_a_censored_run_counts_as_slower_than_every_run_that_reached_the_threshold():
    # times to threshold 100, 200, never against 300, never, never (scores: minus the time, -inf for never):
    # 100 and 200 beat all three (6 pairs); never ties never twice (2 halves) -> 7 / 9
    sooner = improvement_probability([-100, -200, -math.inf], [-300, -math.inf, -math.inf], np.random.default_rng(0))
    assert sooner.mean == pytest.approx(7 / 9)


def test_iqm_is_the_mean_of_the_middle_half_stratified_by_task():
    rng = np.random.default_rng(0)
    assert iqm(np.arange(10, 20), rng).mean == 14.5  # 10 runs: the 2 lowest and 2 highest are cut, mean of 12..17
    outlier = iqm([0, 1, 2, 3, 1000], rng)  # trims int(0.25 * 5) = 1 from each end: mean of 1, 2, 3
    assert outlier.mean == 2.0 and outlier.low <= 2.0 <= outlier.high
    two_maps = np.array([[0.0, 10.0], [1.0, 11.0], [2.0, 12.0], [3.0, 13.0]])  # runs x maps
    assert iqm(two_maps, rng).mean == pytest.approx(np.mean([2, 3, 10, 11]))  # pooled: 8 scores, 2 cut each end


@pytest.mark.filterwarnings("ignore::FutureWarning")  # arch deprecates the RandomState rliable passes it
def test_the_vectorised_stratified_bootstrap_gives_rliables_own_intervals():
    # Same statistic, same resampling scheme (runs within each map; the two conditions independently):
    # the intervals of rliable's get_interval_estimates and ours differ only by Monte Carlo noise.
    data = np.random.default_rng(7)
    x, y = data.normal(0.3, 1.0, size=(6, 3)), data.normal(0.0, 1.0, size=(6, 3))  # 6 runs x 3 maps
    ours = improvement_probability(x, y, np.random.default_rng(1))
    point, ci = rly.get_interval_estimates(
        {"p": (x, y)},
        lambda a, b: np.array([rlm.probability_of_improvement(a, b)]),
        reps=2000,
        random_state=np.random.RandomState(1),
    )
    assert ours.mean == pytest.approx(point["p"][0])
    assert (ours.low, ours.high) == pytest.approx((ci["p"][0, 0], ci["p"][1, 0]), abs=0.03)
    ours = iqm(x, np.random.default_rng(2))
    point, ci = rly.get_interval_estimates(
        {"i": x}, lambda a: np.array([rlm.aggregate_iqm(a)]), reps=2000, random_state=np.random.RandomState(2)
    )
    assert ours.mean == pytest.approx(point["i"][0])
    assert (ours.low, ours.high) == pytest.approx((ci["i"][0, 0], ci["i"][1, 0]), abs=0.06)


def test_a_performance_profile_is_the_fraction_of_runs_above_each_tau():
    scores = np.array([[0.0, 2.0], [1.0, 3.0]])  # 2 runs x 2 maps: 4 scores
    profile, low, high = performance_profile(scores, np.array([-1.0, 0.5, 2.5, 3.0]), np.random.default_rng(0))
    assert profile.tolist() == [1.0, 0.75, 0.25, 0.0]  # above 0.5: 1, 2, 3; above 2.5: 3; nothing above 3
    assert low[0] == high[0] == 1.0 and low[-1] == high[-1] == 0.0  # every resample agrees at the ends
    assert low[1] <= 0.75 <= high[1] and low[1] < high[1]


def test_small_samples_get_t_and_bca_intervals_beside_the_percentile_one():
    rng = np.random.default_rng(0)
    intervals = mean_intervals(np.arange(1, 11), rng)
    # t: 5.5 +- t(0.975, 9) * sd / sqrt(10), sd of 1..10 = 3.0277 -> 5.5 +- 2.2622 * 0.9574
    assert intervals["t"].low == pytest.approx(5.5 - 2.2622 * 0.95743, abs=1e-3)
    assert intervals["t"].high - intervals["t"].low > intervals["percentile"].high - intervals["percentile"].low
    assert intervals["bca"].low < 5.5 < intervals["bca"].high
    assert all(math.isnan(e.low) for e in mean_intervals([3.0, 3.0], rng).values())  # no spread, no interval
