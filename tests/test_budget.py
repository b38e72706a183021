"""The budget rule (dqn_transfer.analysis.budget) on curves whose answers are worked out by hand or
analytically, and its command line (dqn_transfer.cli.budget) on a small pilot written here."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from dqn_transfer.analysis.budget import (
    Budget,
    BudgetRule,
    budget_rule,
    budgets_per_cell,
    converged_step,
    median_plateau_slope,
    plateau_slope,
    slope_trajectory,
)
from dqn_transfer.cli.budget import main as budget_main
from dqn_transfer.experiments.raw_data import RunData, write_data

EVERY = 100  # evaluation interval of the analytic curves, in steps


def exponential(tau: float, end: int = 12_000, start: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``1 - exp(-(t - start) / tau)`` from ``start`` on (0 before), evaluated every :data:`EVERY` steps."""
    steps = np.arange(0, end + 1, EVERY, dtype=np.float64)
    return steps, np.where(steps < start, 0.0, 1.0 - np.exp(-(steps - start) / tau))


def kinked(end: int = 10_000, every: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """Rising 0.1 per 1,000 steps until step 3,000, flat at 0.3 after."""
    steps = np.arange(0, end + 1, every, dtype=np.float64)
    return steps, np.minimum(steps, 3_000) * 0.1 / 1_000


# ------------------------------------------------------------------------------------------ plateau slope


def test_a_straight_line_has_exactly_its_slope():
    steps = np.arange(0, 8_001, 500, dtype=np.float64)
    assert plateau_slope((steps, 0.2 + 0.03 * steps / 1_000)) == pytest.approx(0.03, abs=1e-12)
    assert plateau_slope((steps, np.full(steps.size, 0.7))) == 0.0
    lines = [(steps, 0.1 + slope * steps / 1_000) for slope in (0.05, 0.01, 0.03)]
    assert median_plateau_slope(lines) == pytest.approx(0.03, abs=1e-12)


def test_the_slope_is_fitted_to_the_last_fraction_and_at_least_min_points():
    steps = np.arange(20, dtype=np.float64) * 100
    curve = (steps, np.minimum(steps, 1_600) / 1_000)  # the last 4 of 20 evaluations are flat
    assert plateau_slope(curve, fraction=0.2) == 0.0  # ceil(0.2 * 20) = 4 points
    assert plateau_slope(curve, fraction=0.25) > 0.0  # 5 points: one still rising
    assert plateau_slope(curve, fraction=0.2, min_points=5) > 0.0
    with pytest.raises(ValueError, match="at least 4 evaluations, got 3"):
        plateau_slope((steps[:3], steps[:3]))
    with pytest.raises(ValueError, match="at least 2 points"):
        plateau_slope(curve, min_points=1)


def test_a_set_of_runs_has_the_median_of_their_slopes_not_the_slope_of_their_median_curve():
    """Two runs levelled off at 0 and 1, a third climbing between them: the median curve is the climbing run,
    but the median run has stopped."""
    steps = np.arange(0, 5_001, 500, dtype=np.float64)
    runs = [(steps, np.zeros(steps.size)), (steps, np.ones(steps.size)), (steps, steps / 5_000)]
    median_curve = (steps, np.median([values for _, values in runs], axis=0))
    assert plateau_slope(median_curve) == pytest.approx(0.2)
    assert median_plateau_slope(runs) == 0.0
    assert converged_step(runs, threshold=0.01) == 1_500  # the first step with a slope (4 evaluations)


def test_one_run_jumping_late_does_not_hold_the_cell_back():
    """Four flat runs and one that finds its last chest at the end: the mean of the slopes (the slope of the
    mean curve) is above the threshold, the median is 0."""
    steps = np.arange(0, 8_001, 500, dtype=np.float64)
    flat = [(steps, np.full(steps.size, 0.8)) for _ in range(4)]
    jumping = (steps, np.where(steps >= 7_500, 1.0, 0.8))
    runs = [*flat, jumping]
    assert np.mean([plateau_slope(run) for run in runs]) > 0.01
    assert median_plateau_slope(runs) == 0.0
    assert converged_step(runs, threshold=0.01) == 1_500


# --------------------------------------------------------------------------------------- converged step


def test_an_exponential_approach_converges_where_its_slope_falls_under_the_threshold():
    """``1 - exp(-t/tau)`` gains ``(1000/tau) exp(-t/tau)`` per 1,000 steps, under the threshold from
    ``t* = tau ln(1000 / (tau threshold))``. A line fitted to the evaluations up to S has about the slope at
    its window's middle, and the last 20% of them span ``[0.8 S, S]``: the rule's step is where
    ``0.9 S = t*``, to within one evaluation interval."""
    tau, threshold = 1_000.0, 0.01
    analytic = tau * math.log(1_000 / (tau * threshold))  # 4,605 steps
    expected = analytic / (1 - 0.2 / 2)  # 5,117 steps
    step = converged_step([exponential(tau)], threshold)
    assert step is not None and abs(step - expected) <= EVERY
    steps, slopes = slope_trajectory([exponential(tau)])
    assert slopes[steps == step][0] < threshold <= slopes[steps == step - EVERY][0]


def test_a_curve_flat_before_it_learns_converges_after_it_has_learned():
    """Flat at 0 until step 2,000: the first slopes are 0, under any threshold, but they do not stay under."""
    curve = exponential(1_000.0, start=2_000)
    steps, slopes = slope_trajectory([curve])
    assert slopes[0] == 0.0
    step = converged_step([curve], 0.01)
    assert step is not None and step > 2_000 + 1_000 * math.log(100)


def test_a_curve_that_keeps_rising_has_not_converged():
    steps = np.arange(0, 8_001, 500, dtype=np.float64)
    rising = (steps, 0.05 * steps / 1_000)
    assert converged_step([rising, rising], 0.01) is None
    assert converged_step([rising], 0.06) == 1_500  # under a threshold above its slope, from the first step
    assert converged_step([exponential(1_000.0, end=4_000)], 0.01) is None  # cut before it levels off


def test_a_noisy_plateau_converges_near_the_noiseless_step():
    """Ten runs of the exponential approach with evaluation noise (sd 0.01, a fixed seed): the median run's
    slope crosses the threshold close to where the noiseless curve's does, and the cell converges."""
    rng = np.random.default_rng(0)
    steps, values = exponential(1_000.0, end=20_000)
    runs = [(steps, values + rng.normal(0.0, 0.01, steps.size)) for _ in range(10)]
    clean = converged_step([(steps, values)], 0.01)
    noisy = converged_step(runs, 0.01)
    assert clean is not None and noisy is not None
    assert abs(noisy - clean) <= 1_000


def test_runs_evaluated_at_different_steps_are_cut_at_the_steps_they_share():
    fine, coarse = kinked(every=250), kinked(every=500)
    steps, _ = slope_trajectory([fine, coarse])
    assert steps.tolist() == list(range(1_500, 10_001, 500))
    assert converged_step([fine, coarse], 0.01) == 4_500


def test_bad_thresholds_and_too_few_evaluations_are_value_errors():
    for threshold in (0.0, -0.01, math.nan, math.inf):
        with pytest.raises(ValueError, match="positive slope"):
            converged_step([kinked()], threshold)
    with pytest.raises(ValueError, match="share 3 evaluation steps"):
        converged_step([kinked(end=1_000)], 0.01)
    with pytest.raises(ValueError, match="no runs"):
        converged_step([], 0.01)


# ---------------------------------------------------------------------------------------------- budget


def test_the_budget_is_the_safety_multiple_rounded_up_and_capped():
    """The kinked curve's window of 4 evaluations first lies wholly on the flat part at step 4,500."""
    pilot = [kinked()]
    assert converged_step(pilot, 0.01) == 4_500
    assert budget_rule(pilot, 0.01) == Budget(4_500, 7_000, False, 0.0, 0.0, 10_000, 0.01)  # 1.5 x 4,500 = 6,750
    assert budget_rule(pilot, 0.01, round_to=250).budget == 6_750
    assert budget_rule(pilot, 0.01, safety=1.0).budget == 5_000  # 4,500 rounded up to a multiple of 1,000
    assert budget_rule(pilot, 0.01, safety=1.0, round_to=500).budget == 4_500  # a multiple already: kept
    flat = (np.arange(0.0, 5_000.0, 1_000.0), np.full(5, 0.5))  # converged at its 4th step, 3,000
    assert budget_rule([flat], 0.01, safety=1.1, round_to=100).budget == 3_300  # 1.1 x 3,000 is 3300.0000000000005
    capped = budget_rule(pilot, 0.01, cap=6_000)
    assert (capped.budget, capped.capped, capped.slope_at_budget) == (6_000, True, 0.0)
    beyond = budget_rule(pilot, 0.01, safety=3.0)
    assert (beyond.budget, beyond.capped, beyond.slope_at_budget) == (14_000, False, None)  # past the pilot


def test_a_cell_that_did_not_converge_gets_the_cap_flagged():
    steps = np.arange(0, 8_001, 500, dtype=np.float64)
    budget = budget_rule([(steps, 0.05 * steps / 1_000)], 0.01, cap=24_000)
    assert not budget.converged
    assert (budget.converged_step, budget.budget, budget.capped, budget.slope_at_budget) == (None, 24_000, True, None)
    assert budget.final_slope == pytest.approx(0.05)
    assert budget.pilot_steps == 8_000
    assert budget.margin == pytest.approx(0.04)  # only the last slope, 0.05, decided: 0.04 above 0.01


def test_the_margin_is_the_closest_call_among_the_slopes_that_decided():
    """The kinked curve: at 4,000 the window 2,500..4,000 (0.25, 0.3, 0.3, 0.3) has slope 0.03 per 1,000 steps
    (covariance 0.0375 / variance 1.25), the last not below 0.01; every window after it is flat (slope 0). The
    decision's closest call is a flat window, 0.01 below the threshold. A straight line of slope 0.0099 is
    below 0.01 everywhere: converged at its first slope, by a margin of 0.0001."""
    assert budget_rule([kinked()], 0.01).margin == pytest.approx(0.01, abs=1e-12)
    assert budget_rule([kinked()], 0.025).margin == pytest.approx(0.005, abs=1e-12)  # 0.03 - 0.025
    steps = np.arange(0, 8_001, 500, dtype=np.float64)
    close = budget_rule([(steps, 0.0099 * steps / 1_000)], 0.01)
    assert (close.converged_step, close.margin) == (1_500, pytest.approx(0.0001, abs=1e-12))


def test_the_rule_refuses_a_safety_below_one_and_a_non_positive_cap_or_rounding():
    for bad in ({"safety": 0.5}, {"safety": math.nan}, {"cap": 0}, {"round_to": 0}):
        with pytest.raises(ValueError):
            budget_rule([kinked()], 0.01, **bad)


def test_the_rule_applies_per_cell_with_the_same_parameters():
    steps = np.arange(0, 8_001, 500, dtype=np.float64)
    budgets = budgets_per_cell(
        {"flat": [kinked()], "rising": [(steps, 0.05 * steps / 1_000)]}, BudgetRule(0.01, cap=20_000)
    )
    assert list(budgets) == ["flat", "rising"]
    assert (budgets["flat"].budget, budgets["rising"].budget) == (7_000, 20_000)


# -------------------------------------------------------------------------------------------- the command


def pilot_run(name: str, algorithm: str, team: int, seed: int, curve: tuple[np.ndarray, np.ndarray]) -> RunData:
    """A claim2 run on a map whose optimal team return is 100: its score curve is ``curve``."""
    steps, scores = curve
    config = {
        "seed": seed,
        "agent": {"algorithm": algorithm, "share_parameters": False},
        "env": {"mode": "cooperative", "num_agents": team, "map_seed": 0},
        "transfer": {"exchange": "none"},
    }
    metrics = {"team_return": tuple(float(v) for v in 100.0 * scores)}
    return RunData("claim2", name, config, tuple(int(s) for s in steps), metrics, 0, 100.0)


@pytest.fixture
def pilot(tmp_path: Path) -> Path:
    """Three cells of three runs: Double DQN and SARSA at m = 2 level off (converged at 4,500), SARSA at
    m = 6 keeps rising 0.05 per 1,000 steps; the Double DQN cell comes first in the file."""
    steps = np.arange(0, 10_001, 500, dtype=np.float64)
    cells = [("double_dqn", 2, kinked()), ("sarsa", 2, kinked()), ("sarsa", 6, (steps, 0.05 * steps / 1_000))]
    runs = [
        pilot_run(f"{job}/seed_{seed}", algorithm, team, seed, curve)
        for job, (algorithm, team, curve) in enumerate(cells)
        for seed in range(3)
    ]
    path = tmp_path / "claim2.jsonl"
    write_data(path, runs)
    return path


def test_the_command_prints_one_row_per_cell_the_primary_learner_first(pilot, capsys):
    assert budget_main(["--pilot", str(pilot), "--threshold", "0.01"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and "---" not in line]
    assert rows == [
        "| learner | mode | m | runs | converged step | budget | capped | slope at budget | final slope |",
        "| sarsa | cooperative | 2 | 3 | 4,500 | 7,000 | no | +0.0000 | +0.0000 |",
        "| sarsa | cooperative | 6 | 3 | not converged within the pilot (10,000) | 32,000 (cap) | yes "
        "| beyond the pilot | +0.0500 |",
        "| double_dqn | cooperative | 2 | 3 | 4,500 | 7,000 | no | +0.0000 | +0.0000 |",
    ]
    assert "2 of 3 cells converged within the pilot." in out
    assert "1 did not" in out and "not a measurement" in out


def test_the_commands_parameters_reach_the_rule(pilot, capsys):
    assert budget_main(["--pilot", str(pilot), "--threshold", "0.06", "--safety", "2", "--cap", "12000"]) == 0
    out = capsys.readouterr().out
    assert "| sarsa | cooperative | 6 | 3 | 1,500 | 3,000 | no |" in out  # 0.05 per 1,000 steps is under 0.06
    assert "3 of 3 cells converged" in out


def test_a_pilot_or_threshold_that_cannot_be_used_is_one_error_line(pilot, tmp_path, capsys):
    assert budget_main(["--pilot", str(tmp_path / "missing.jsonl"), "--threshold", "0.01"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot read") and err.count("\n") == 1
    assert budget_main(["--pilot", str(pilot), "--threshold", "-0.01"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: the threshold is a positive slope") and err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_info:
        budget_main(["--pilot", str(pilot), "--threshold", "abc"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: argument --threshold") and err.count("\n") == 1
    (tmp_path / "empty.jsonl").write_text("")
    assert budget_main(["--pilot", str(tmp_path / "empty.jsonl"), "--threshold", "0.01"]) == 2
    assert capsys.readouterr().err == "error: the pilot holds no runs\n"
    other = tmp_path / "transfer.jsonl"
    other.write_text(pilot.read_text().replace('"experiment":"claim2"', '"experiment":"transfer"'))
    assert budget_main(["--pilot", str(other), "--threshold", "0.01"]) == 2
    assert capsys.readouterr().err.startswith("error: no budget cells for experiment 'transfer'")
