"""Replicas on every core (``training/workers.py``): a batch split across worker processes is the run one
process makes, bit for bit; Ctrl-C stops every worker at a checkpoint and the run resumes to the same
end; a worker's failure is the run's, in one line for a user error; ``auto`` shares the cores with a
sweep's other jobs."""

from __future__ import annotations

import dataclasses
import json
import signal
import time
from pathlib import Path

import pytest
from conftest import TRAIN_TIMEOUT, read_metrics, run_train, start_train, without_timing
from test_replicas import config

from dqn_transfer.config import ConfigError
from dqn_transfer.storage.checkpoint import load_training_state
from dqn_transfer.training import workers
from dqn_transfer.training.plan import plan_run

RUN = (
    "agent=dqn",
    "env.size=5",
    "env.num_treasures=2",
    "env.num_agents=2",
    "env.map_seed=1",
    "agent.hidden=[16]",
    "agent.learning_starts=100",
    "eval_every=250",
    "eval_episodes=2",
    "replicas.seeds=3",
)


def run_files(run_dir: Path) -> dict[str, object]:
    """Every replica's agent files, resume state (its arrays, its counters) and evaluation records (without
    their clock stamps); a resumed run's state differs only in its config's ``resume``."""
    files: dict[str, object] = {}
    for replica in sorted(p for p in run_dir.iterdir() if p.is_dir() and p.name.startswith("seed_")):
        for path in sorted((replica / "checkpoints").glob("agent_*.safetensors")):
            files[f"{replica.name}/{path.name}"] = path.read_bytes()
        arrays, meta = load_training_state(replica / "checkpoints" / "training_state.safetensors")
        files[f"{replica.name}/state"] = {name: value.tobytes() for name, value in arrays.items()}
        files[f"{replica.name}/counters"] = meta["counters"]
        files[f"{replica.name}/metrics"] = without_timing(read_metrics(replica))
    return files


def test_two_workers_make_the_run_of_one_process(tmp_path):
    one = run_train(tmp_path, *RUN, "total_steps=1000", "replicas.workers=1", run_dir=tmp_path / "one")
    two = run_train(tmp_path, *RUN, "total_steps=1000", "replicas.workers=2", run_dir=tmp_path / "two")
    assert "3 replicas in 2 worker processes" in two.output and "worker processes" not in one.output
    files_one, files_two = run_files(tmp_path / "one"), run_files(tmp_path / "two")
    assert len(files_one) == 3 * (2 + 3) and files_one.keys() == files_two.keys()  # 2 agents, state, counters, metrics
    for name, value in files_one.items():
        assert files_two[name] == value, name
    index_one, index_two = (json.loads((tmp_path / run / "replicas.json").read_text()) for run in ("one", "two"))
    assert index_two["replicas"] == index_one["replicas"] == ["seed_0", "seed_1", "seed_2"]


@pytest.mark.slow
def test_ctrl_c_stops_every_worker_at_a_checkpoint_and_the_run_resumes_to_the_same_end(tmp_path):
    run_train(tmp_path, *RUN, "total_steps=30000", "replicas.workers=1", run_dir=tmp_path / "reference")
    run_dir = tmp_path / "stopped"
    proc = start_train(tmp_path, *RUN, "total_steps=30000", "replicas.workers=2", run_dir=run_dir)
    deadline = time.monotonic() + TRAIN_TIMEOUT
    while not all(len(read_metrics(run_dir / f"seed_{s}")) >= 3 for s in range(3)):  # every worker in its loop
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=60) == 130
    output = run_dir.with_suffix(".out").read_text()
    assert "Traceback" not in output
    assert f"resume with: python train.py resume=true hydra.run.dir={run_dir}" in output
    assert output.count("SIGINT received") == 2  # once per worker: the terminal's signal is forwarded once
    run_train(tmp_path, "resume=true", run_dir=run_dir)  # with the default workers, whatever their steps
    assert run_files(run_dir) == run_files(tmp_path / "reference")


def test_a_workers_user_error_is_the_runs_one_line(tmp_path, monkeypatch):
    """A share's trainer refuses to start (as a corrupt checkpoint would make it): the run raises that
    error, for the command line's one-line report, after the other worker stopped."""
    plan = plan_run(dataclasses.replace(config(seeds=2), total_steps=200))

    class Refusing(workers.Trainer):
        def run(self):
            if self.plan.first_replica == 1:
                raise ConfigError("replica 1 cannot start")
            return super().run()

    monkeypatch.setattr(workers, "Trainer", Refusing)
    with pytest.raises(ConfigError, match="replica 1 cannot start"):
        workers.ReplicaWorkers(plan, tmp_path / "run", [(0, 1), (1, 1)]).run()


def test_shares_are_even_and_a_resumed_batch_is_grouped_by_step(tmp_path, monkeypatch):
    plan = plan_run(config(seeds=5))
    assert workers.shares(plan, tmp_path, 2) == [(0, 2), (2, 3)]
    assert workers.shares(plan, tmp_path, 5) == [(r, 1) for r in range(5)]
    resumed = plan.resuming(True)
    monkeypatch.setattr(workers, "checkpoint_steps", lambda plan, run_dir: [700, 700, 700, 650, 650])
    assert workers.shares(resumed, tmp_path, 1) == [(0, 3), (3, 2)]  # one process cannot hold two steps
    assert workers.shares(resumed, tmp_path, 2) == [(0, 3), (3, 2)]
    assert workers.shares(resumed, tmp_path, 5) == [(0, 1), (1, 1), (2, 1), (3, 1), (4, 1)]


@pytest.mark.parametrize(
    "setting, cores, jobs, replicas, expected",
    [("auto", 2, 1, 10, 2), ("auto", 2, 2, 10, 1), ("auto", 8, 2, 10, 4), ("auto", 8, 1, 3, 3), ("3", 2, 1, 10, 3)],
)
def test_auto_uses_the_cores_left_to_each_job_at_once(monkeypatch, setting, cores, jobs, replicas, expected):
    monkeypatch.setattr(workers, "available_cores", lambda: cores)
    monkeypatch.setattr(workers, "sweep_jobs_at_once", lambda: jobs)
    assert workers.worker_count(setting, replicas) == expected


@pytest.mark.parametrize("value", ["0", "many", "-2"])
def test_a_bad_workers_setting_is_refused_in_one_line(tmp_path, value):
    result = run_train(tmp_path, *RUN, f"replicas.workers={value}", check=False)
    assert result.returncode == 1 and "Traceback" not in result.output
    assert f"replicas.workers must be auto or a number of processes >= 1, got {value}" in result.output
