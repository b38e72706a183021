"""What a run says on the console and writes to its logs: each game's own metrics, one line per
evaluation of a batch of replicas (their per-replica numbers in their own files)."""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import numpy as np
import pytest
from conftest import read_metrics

from dqn_transfer.config import AgentConfig, ReplicasConfig, TrainConfig
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train

LBF = "dqn_transfer.envs.lbf:parallel_env"
TREASURE_HUNT_ONLY = ("success_rate", "trap_rate", "after_clear_rate", "return_after_clear", "treasures")


def quick_run(run_dir: Path, caplog: pytest.LogCaptureFixture, env: EnvConfig, seeds: int = 1) -> list[str]:
    """A 40-step DQN run (or batch of ``seeds`` replicas) in this process, evaluated every 20 steps, its
    scalars in ``scalars.csv``; returns the lines it logged."""
    config = TrainConfig(
        env=env,
        agent=AgentConfig(hidden=[8], learning_starts=10),
        replicas=ReplicasConfig(seeds=seeds),
        total_steps=40,
        eval_every=20,
        eval_episodes=2,
        progress=False,
        logger=["csv"],
    )
    with caplog.at_level(logging.INFO, logger="dqn_transfer.train"):
        train(plan_run(config), run_dir)
    return [record.getMessage() for record in caplog.records if record.name == "dqn_transfer.train"]


def csv_tags(run_dir: Path) -> set[str]:
    with (run_dir / "scalars.csv").open(newline="") as f:
        return {row["tag"] for row in csv.DictReader(f)}


def test_another_games_lines_and_logs_show_only_what_it_measures(tmp_path, caplog):
    run_dir = tmp_path / "lbf"
    lines = quick_run(run_dir, caplog, EnvConfig(factory=LBF, kwargs={"size": 5, "max_steps": 10}))
    evals = [line for line in lines if line.startswith("eval step")]
    done = [line for line in lines if line.startswith("done:")]
    assert len(evals) == 3 and len(done) == 1  # steps 0, 20, 40
    records = read_metrics(run_dir)
    for line, record in zip(evals, records):
        assert line == (
            f"eval step {record['step']}: team_return {record['team_return']:.1f} "
            f"episode_length {record['episode_length']:.1f}"
        )
    assert not [line for line in [*evals, *done] if any(word in line for word in TREASURE_HUNT_ONLY)]
    assert "last eval team_return" in done[0] and "episode_length" in done[0]
    tags = csv_tags(run_dir)
    assert {"eval/team_return", "eval/episode_length", "team/return"} <= tags
    assert not [tag for tag in tags if any(word in tag for word in TREASURE_HUNT_ONLY)]
    # The record keeps every key (metrics.jsonl reads alike for every game), the chests' and traps' at 0.
    assert records[-1]["success_rate"] == records[-1]["trap_rate"] == 0.0


def test_the_treasure_hunts_lines_and_logs_show_its_chests_and_traps(tmp_path, caplog):
    run_dir = tmp_path / "hunt"
    lines = quick_run(run_dir, caplog, EnvConfig())
    record = read_metrics(run_dir)[0]
    assert [line for line in lines if line.startswith("eval step")][0] == (
        f"eval step 0: team_return {record['team_return']:.1f} success_rate {record['success_rate']:.2f} "
        f"trap_rate {record['trap_rate']:.2f}"
    )
    assert {"eval/success_rate", "eval/trap_rate", "team/trap_rate", "team/treasures_collected"} <= csv_tags(run_dir)


def test_an_evaluation_of_replicas_is_one_line_of_mean_min_and_max(tmp_path, caplog):
    lines = quick_run(tmp_path / "batch", caplog, EnvConfig(), seeds=3)
    evals = [line for line in lines if line.startswith("eval step")]
    assert len(evals) == 3  # one per evaluation, not one per replica
    per_replica = [read_metrics(tmp_path / "batch" / f"seed_{seed}") for seed in range(3)]
    assert [len(records) for records in per_replica] == [3, 3, 3]  # each replica's records in its own file
    for evaluation, line in enumerate(evals):
        returns = [records[evaluation]["team_return"] for records in per_replica]
        traps = [records[evaluation]["trap_rate"] for records in per_replica]
        step = per_replica[0][evaluation]["step"]
        assert line.startswith(f"eval step {step}, mean [min, max] of 3 replicas: ")
        assert f"team_return {np.mean(returns):.1f} [{min(returns):.1f}, {max(returns):.1f}]" in line
        assert f"trap_rate {np.mean(traps):.2f} [{min(traps):.2f}, {max(traps):.2f}]" in line
    done = [line for line in lines if line.startswith("done:")][0]
    assert "(mean of 3 replicas) team_return" in done and "episodes a replica" in done
