"""Judging learning over seeds (dqn_transfer.analysis.reliability) on curves worked out by hand, and the
learning tables' command (dqn_transfer.cli.learning) on data written here."""

from __future__ import annotations

import numpy as np
import pytest

from dqn_transfer.analysis.reliability import RunOutcome, parity, reliability, run_outcome
from dqn_transfer.cli.learning import main as learning_main
from dqn_transfer.experiments.raw_data import RunData, write_data

STEPS = list(range(0, 8_001, 1_000))  # 9 evaluations


def test_a_run_is_solved_by_most_of_its_last_five_evaluations():
    late = run_outcome(STEPS, [0, 0, 0, 0, 0.5, 1, 0, 1, 1], 1.0)  # last five: 0.5, 1, 0, 1, 1 -> 3 solve
    assert late.solved and late.first_solved == 5_000 and not late.lost
    assert late.kept == pytest.approx(3 / 4)  # from step 5,000: 1, 0, 1, 1
    assert late.auc == pytest.approx(3.5 / 9) and late.final == pytest.approx(3.5 / 5)
    lost = run_outcome(STEPS, [0, 1, 1, 1, 1, 1, 0, 0, 1], 1.0)  # last five: 1, 1, 0, 0, 1 -> 3 solve
    assert lost.solved
    lost = run_outcome(STEPS, [0, 1, 1, 1, 1, 0, 0, 0, 1], 1.0)  # last five: 1, 0, 0, 0, 1 -> 2: lost it
    assert not lost.solved and lost.lost and lost.first_solved == 1_000 and lost.kept == pytest.approx(5 / 8)
    never = run_outcome(STEPS, [0.5] * 9, 1.0)
    assert (never.solved, never.first_solved, never.kept, never.lost) == (False, None, None, False)
    with pytest.raises(ValueError, match="at least 5 evaluations"):
        run_outcome(STEPS[:4], [1.0] * 4, 1.0)


def outcome(solved: bool, auc: float, first: int | None = 1_000) -> RunOutcome:
    return RunOutcome(solved, first, None if first is None else 1.0, auc, auc)


def test_reliability_counts_the_runs_that_solved_kept_and_lost_it():
    runs = [
        run_outcome(STEPS, [0, 0, 1, 1, 1, 1, 1, 1, 1], 1.0),  # solved from 2,000, kept 1
        run_outcome(STEPS, [0, 0, 0, 0, 1, 1, 1, 0, 1], 1.0),  # from 4,000, kept 4/5, solved
        run_outcome(STEPS, [0, 1, 0, 0, 0, 0, 0, 0, 1], 1.0),  # from 1,000, kept 2/8, lost it
        run_outcome(STEPS, [0] * 9, 1.0),  # never
    ]
    r = reliability(runs)
    assert (r.runs, r.solved, r.ever_solved, r.lost) == (4, 2, 3, 1)
    assert r.kept == pytest.approx((1 + 4 / 5 + 2 / 8) / 3)
    assert r.median_first_solved == 2_000
    assert (r.final_mean, r.final_min, r.final_max) == pytest.approx(((1 + 0.8 + 0.2 + 0) / 4, 0.0, 1.0))


def test_parity_counts_solved_runs_and_ranks_the_areas():
    """Two maps, 4 runs per engine each. B's areas all exceed A's on both maps: P(B > A) is 1; the solved
    counts 8/8 against 0/8 give Fisher's two-sided p = 2 / C(16, 8) = 2 / 12,870."""
    a = [[outcome(False, 0.1 * i, None) for i in range(4)] for _ in range(2)]
    b = [[outcome(True, 0.5 + 0.1 * i) for i in range(4)] for _ in range(2)]
    result = parity(a, b, np.random.default_rng(0))
    assert (result.auc.mean, result.auc.low, result.auc.high) == (1.0, 1.0, 1.0)
    assert (result.solved_a, result.solved_b, result.runs_a, result.runs_b) == (0, 8, 8, 8)
    assert result.fisher_p == pytest.approx(2 / 12_870)
    assert not result.alike
    same = parity(a, a, np.random.default_rng(0))
    assert same.auc.mean == 0.5 and same.fisher_p == 1.0 and same.alike
    with pytest.raises(ValueError, match="same tasks"):
        parity(a, b[:1], np.random.default_rng(0))


def _run(name: str, engine: str, map_seed: int, seed: int, success: list[float]) -> RunData:
    config = {"seed": seed, "env": {"map_seed": map_seed}, "agent": {"engine": engine}}
    steps = tuple(range(0, 1_000 * len(success), 1_000))
    team_return = tuple(100.0 * s for s in success)
    return RunData(
        name,
        f"0/seed_{seed}",
        config,
        steps,
        {"success_rate": tuple(success), "team_return": team_return},
        0,
        None,
    )


def test_the_tables_come_from_the_data_alone(tmp_path, capsys):
    solved, unsolved = [0, 0, 1, 1, 1, 1, 1], [0, 0, 0, 0, 1, 0, 0]
    write_data(tmp_path / "data" / "default.jsonl", [_run("default", "auto", 6, s, solved) for s in range(3)])
    parity_runs = [_run("parity", "numpy", m, s, solved) for m in (101, 102) for s in range(2)]
    parity_runs += [_run("parity", "torch", m, s, unsolved if s == 0 else solved) for m in (101, 102) for s in range(2)]
    write_data(tmp_path / "data" / "parity.jsonl", parity_runs)
    assert learning_main(["table", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "TABLES.md").read_text()
    assert "| `python train.py` | 3 | 3/3 | 3/3 | 0 | 1.00 | 2,000 | success_rate 1.00 [1.00, 1.00] |" in text
    assert "| runs solved at the end | 4/4 | 2/4 |" in text and "(map 101: 2 vs 1, map 102: 2 vs 1)" in text
    assert text in capsys.readouterr().out


def test_the_tables_of_no_data_are_one_line(tmp_path, capsys):
    assert learning_main(["table", "--out", str(tmp_path / "nothing")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "run the sweeps first" in err
    assert not (tmp_path / "nothing").exists()
    assert learning_main(["run", "--out", str(tmp_path), "--only", "nosuch"]) == 1
    assert "unknown experiment(s) nosuch" in capsys.readouterr().err
