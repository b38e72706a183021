"""The pretrained-source cache (docs/transfer.md, "Where the source comes from"): a cache entry
``<cache_dir>/<hash>/`` appears whole or not at all, parallel jobs pretrain it once, an interrupted or
failed pretraining leaves nothing, a killed one's leftovers are cleaned by the next, and a complete
entry is reused without pretraining.

What is checked is what a user sees: the cache directory's listing, the log lines, the checkpoint's
own ``meta.steps`` (read with ``safetensors`` alone), and the ``transfer_source`` each run records in
the first line of its ``metrics.jsonl``. The two tests with real ``python train.py`` processes are
``slow``; the others pretrain a Q-learning source for 200 steps in process (a fraction of a second).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import TRAIN_TIMEOUT, agent_meta, assert_named_paths_exist, run_train, start_train

import dqn_transfer.sources.resolve
from dqn_transfer.config import AgentConfig, ReplicasConfig, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sources.resolve import transfer_sources
from dqn_transfer.training.plan import plan_run
from dqn_transfer.transfer.mapping import TransferError

# Two agents, two chests (row 0 col 4, row 4 col 4), one trap (row 2 col 2), no obstacles.
MAP = "0...T\n.....\n..X..\n.....\n1...T\n"
PRETRAIN_STEPS = 200
PRETRAINING, REUSING, WAITING = "pretraining a source agent", "reusing the pretrained source", "waiting for another job"
# The command line of the process tests: a small DQN on MAP, every run's source cached in cache/.
CLI = (
    "env.layout_file=map.txt",
    "eval_episodes=2",
    "agent=dqn",
    "agent.hidden=[32]",
    "agent.batch_size=32",
    "agent.learning_starts=50",
    "transfer=on",
    "transfer.cache_dir=cache",
)


def config(cache: Path, pretrain_steps: int = PRETRAIN_STEPS) -> TrainConfig:
    env = EnvConfig(layout=MAP, size=5, num_treasures=2, num_traps=1, num_agents=2, complexity=0.0)
    transfer = TransferConfig(enabled=True, cache_dir=str(cache), pretrain_steps=pretrain_steps)
    return TrainConfig(
        env=env,
        agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.5),
        seed=0,
        total_steps=0,
        eval_episodes=1,
        progress=False,
        transfer=transfer,
    )


def listing(cache: Path) -> tuple[list[str], list[str]]:
    """(cache entries, hidden directories: temporary or half-removed ones) of a cache directory."""
    dirs = sorted(p.name for p in cache.iterdir() if p.is_dir())
    return [d for d in dirs if not d.startswith(".")], [d for d in dirs if d.startswith(".")]


def checkpoint_steps(path: Path) -> int:
    return agent_meta(path)["steps"]


def evaluated_steps(metrics: Path) -> list[int]:
    return [json.loads(line)["step"] for line in metrics.read_text().splitlines() if line.strip()]


@pytest.fixture
def cache(tmp_path: Path) -> Path:
    return tmp_path / "cache"


@pytest.fixture
def entry(cache: Path, tmp_path: Path) -> Path:
    """A cache entry pretrained once (its name is the source config's hash)."""
    checkpoint = transfer_sources(plan_run(config(cache)), tmp_path)[0][0]
    return checkpoint.parent.parent


# ------------------------------------------------------------------------- in process


def test_a_pretraining_fills_one_entry_and_nothing_else(cache, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    checkpoint = transfer_sources(plan_run(config(cache)), tmp_path)[0][0]
    entries, hidden = listing(cache)
    assert len(entries) == 1 and hidden == []
    assert checkpoint == cache / entries[0] / "checkpoints" / "agent_0.safetensors"
    assert checkpoint_steps(checkpoint) == PRETRAIN_STEPS
    assert caplog.text.count(PRETRAINING) == 1 and REUSING not in caplog.text
    assert f"cached in {cache / entries[0]}" in caplog.text
    # The entry is an ordinary run directory: its evaluations end at the last pretraining step.
    assert evaluated_steps(cache / entries[0] / "metrics.jsonl")[-1] == PRETRAIN_STEPS


def test_a_complete_entry_is_reused_without_pretraining(cache, entry, tmp_path, monkeypatch, caplog):
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    (entry / ".lock").touch()  # as the in-place layout of earlier versions left it: still a complete entry
    checkpoint = entry / "checkpoints" / "agent_0.safetensors"
    stamp = checkpoint.stat().st_mtime_ns

    def no_training(*args, **kwargs):
        raise AssertionError("pretrained again")

    monkeypatch.setattr(dqn_transfer.sources.resolve, "train_on_cores", no_training)
    assert transfer_sources(plan_run(config(cache)), tmp_path)[0][0] == checkpoint
    assert REUSING in caplog.text and PRETRAINING not in caplog.text
    assert checkpoint.stat().st_mtime_ns == stamp


@pytest.mark.parametrize("failure", [KeyboardInterrupt, RuntimeError])
def test_a_failed_pretraining_leaves_nothing(cache, tmp_path, monkeypatch, failure):
    """The pretraining runs to its end (every file written), then fails before it is complete."""
    real_train, used = dqn_transfer.sources.resolve.train_on_cores, []

    def train_then_fail(config, run_dir, **kwargs):
        used.append(Path(run_dir))
        real_train(config, run_dir, **kwargs)
        assert (Path(run_dir) / "metrics.jsonl").stat().st_size > 0
        raise failure()

    monkeypatch.setattr(dqn_transfer.sources.resolve, "train_on_cores", train_then_fail)
    with pytest.raises(failure):
        transfer_sources(plan_run(config(cache)), tmp_path)[0][0]
    assert used and used[0].parent == cache  # it pretrained beside the entry it would have become ...
    assert listing(cache) == ([], [])  # ... and nothing of it is left
    monkeypatch.setattr(dqn_transfer.sources.resolve, "train_on_cores", real_train)
    checkpoint = transfer_sources(plan_run(config(cache)), tmp_path)[0][0]  # the next run pretrains afresh
    assert checkpoint_steps(checkpoint) == PRETRAIN_STEPS


def test_a_killed_pretrainings_temp_dir_is_removed_by_the_next(cache, entry, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    key = entry.name
    shutil.rmtree(entry)
    stale = cache / f".{key}.tmp-999999-deadbeef"  # what a SIGKILL during pretraining leaves
    (stale / "tb").mkdir(parents=True)
    (stale / "metrics.jsonl").write_text('{"step": 0, "team_return": -1.0}\n')
    other = cache / ".0123456789abcdef.tmp-1-cafe0000"  # another source's: another job may be using it
    other.mkdir()
    checkpoint = transfer_sources(plan_run(config(cache)), tmp_path)[0][0]
    assert PRETRAINING in caplog.text
    assert checkpoint_steps(checkpoint) == PRETRAIN_STEPS
    assert listing(cache) == ([key], [other.name])


def test_an_unfinished_entry_of_the_in_place_layout_is_replaced(cache, entry, tmp_path, caplog):
    """Earlier versions pretrained into <hash>/ itself; a killed one left a checkpoint of fewer steps
    and the evaluations it had made. The next pretraining starts that entry afresh."""
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    shorter = transfer_sources(
        plan_run(config(tmp_path / "other_cache", pretrain_steps=PRETRAIN_STEPS // 2)), tmp_path
    )[0][0]
    fresh_steps = evaluated_steps(entry / "metrics.jsonl")
    shutil.rmtree(entry)
    (entry / "checkpoints").mkdir(parents=True)
    shutil.copy(shorter, entry / "checkpoints" / "agent_0.safetensors")
    (entry / ".lock").touch()
    (entry / "metrics.jsonl").write_text('{"step": 0, "team_return": -1.0, "aborted": true}\n' * 3)
    caplog.clear()
    checkpoint = transfer_sources(plan_run(config(cache)), tmp_path)[0][0]
    assert PRETRAINING in caplog.text
    assert checkpoint_steps(checkpoint) == PRETRAIN_STEPS
    assert evaluated_steps(entry / "metrics.jsonl") == fresh_steps  # the aborted evaluations are gone
    assert "aborted" not in (entry / "metrics.jsonl").read_text()
    assert listing(cache) == ([entry.name], [])


def test_an_unusable_cache_dir_is_one_message(tmp_path):
    (tmp_path / "a_file").write_text("")
    with pytest.raises(TransferError) as err:
        transfer_sources(plan_run(config(tmp_path / "a_file" / "cache")), tmp_path)[0][0]
    assert str(err.value) == (
        f"cannot use the pretraining cache {tmp_path / 'a_file' / 'cache'}: Not a directory "
        "(set transfer.cache_dir to a writable directory)"
    )


# ------------------------------------------------------------------------- real processes


def wait_for(condition: Callable[[], object], procs: list[subprocess.Popen], what: str, timeout: float = 120):
    """Poll ``condition`` until it returns something true; fail if a process ends before that."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if result := condition():
            return result
        if any(p.poll() is not None for p in procs):
            pytest.fail(f"a run ended before {what}")
        time.sleep(0.02)
    pytest.fail(f"timed out waiting for {what}")


def pretraining_metrics(cache: Path) -> Path | None:
    """The metrics.jsonl of a pretraining in progress, once it holds an evaluation."""
    for metrics in cache.glob(".*.tmp-*/metrics.jsonl"):
        try:
            if metrics.stat().st_size > 0:
                return metrics
        except FileNotFoundError:  # renamed or removed meanwhile
            continue
    return None


def stop_all(procs: list[subprocess.Popen]) -> None:
    for proc in procs:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_two_cold_runs_at_once_pretrain_once(tmp_path):
    (tmp_path / "map.txt").write_text(MAP)
    cache = tmp_path / "cache"
    overrides = (*CLI, "transfer.pretrain_steps=600", "total_steps=40", "eval_every=20")
    procs = [start_train(tmp_path, *overrides, run_dir=tmp_path / f"run{i}") for i in range(2)]
    outputs = [tmp_path / f"run{i}.out" for i in range(2)]
    try:
        # Make the race certain: pause the job that pretrains until the other one waits for the lock.
        metrics = wait_for(lambda: pretraining_metrics(cache), procs, "a pretraining evaluated")
        pid = int(metrics.parent.name.split(".tmp-")[1].split("-")[0])  # .<hash>.tmp-<pid>-<random>
        first = [p.pid for p in procs].index(pid)
        os.kill(pid, signal.SIGSTOP)
        assert metrics.exists(), "the pretraining finished before it could be paused"
        wait_for(lambda: WAITING in outputs[1 - first].read_text(), procs, "the other job to wait")
        os.kill(pid, signal.SIGCONT)
        for proc in procs:
            proc.wait(timeout=TRAIN_TIMEOUT)
    finally:
        stop_all(procs)
    logs = [out.read_text() for out in outputs]
    assert [proc.returncode for proc in procs] == [0, 0], "\n".join(logs)
    assert logs[first].count(PRETRAINING) == 1 and logs[1 - first].count(PRETRAINING) == 0
    assert REUSING in logs[1 - first]
    entries, hidden = listing(cache)
    assert len(entries) == 1 and hidden == []
    checkpoint = cache / entries[0] / "checkpoints" / "agent_0.safetensors"
    sources = [
        json.loads((tmp_path / f"run{i}" / "metrics.jsonl").read_text().splitlines()[0])["transfer_source"]
        for i in range(2)
    ]
    assert sources[0]["digest"] == sources[1]["digest"]
    assert sources[0]["source"] == sources[1]["source"] == str(checkpoint)


@pytest.mark.slow
def test_ctrl_c_during_pretraining_leaves_nothing(tmp_path):
    (tmp_path / "map.txt").write_text(MAP)
    cache = tmp_path / "cache"
    # Far more pretraining steps than the test waits for: the signal always lands mid-pretraining.
    proc = start_train(tmp_path, *CLI, "transfer.pretrain_steps=200000", "total_steps=40", run_dir=tmp_path / "run")
    try:
        wait_for(lambda: pretraining_metrics(cache), [proc], "the pretraining evaluated")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=TRAIN_TIMEOUT)
    finally:
        stop_all([proc])
    output = (tmp_path / "run.out").read_text()
    assert proc.returncode != 0, output
    assert [p.name for p in cache.iterdir() if p.is_dir()] == [], output  # no entry, no temp dir


def test_replicas_pretrain_their_missing_sources_as_one_batch(cache, tmp_path, monkeypatch, caplog):
    """Three replicas, no source cached: one pretraining run of three replicas fills three entries, each
    the very entry (same hash, same tensors) the lone pretraining of its seed makes. Later, a batch
    reuses them all, and with one entry gone it pretrains only that one, alone."""
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    real, runs = dqn_transfer.sources.resolve.train_on_cores, []

    def counted(plan, *args, **kwargs):
        runs.append(plan.config.replicas.seeds)
        return real(plan, *args, **kwargs)

    monkeypatch.setattr(dqn_transfer.sources.resolve, "train_on_cores", counted)
    batch = dataclasses.replace(config(cache), replicas=ReplicasConfig(seeds=3))
    per_replica = transfer_sources(plan_run(batch), tmp_path)
    sources = [targets[0] for targets in per_replica]  # the default team: every agent from the one source
    assert runs == [3] and len(set(sources)) == 3 and all(targets == [targets[0]] * 2 for targets in per_replica)
    entries, hidden = listing(cache)
    assert sorted(entries) == sorted(p.parent.parent.name for p in sources) and hidden == []
    for seed, source in enumerate(sources):
        lone = transfer_sources(plan_run(dataclasses.replace(config(tmp_path / "lone_cache"), seed=seed)), tmp_path)[0][
            0
        ]
        assert source.parent.parent.name == lone.parent.parent.name  # the same source config hash
        assert checkpoint_steps(source) == PRETRAIN_STEPS
        assert agent_meta(source)["digest"] == agent_meta(lone)["digest"]
    runs.clear()
    assert transfer_sources(plan_run(batch), tmp_path) == per_replica and runs == []
    shutil.rmtree(sources[1].parent.parent)
    assert transfer_sources(plan_run(batch), tmp_path) == per_replica and runs == [1]


@pytest.mark.slow
def test_a_transfer_runs_lines_name_existing_paths_and_tag_the_pretraining(tmp_path):
    """The pretraining's ``done:`` line named its ``.tmp-<pid>-<random>`` work directory (checkpoints,
    tensorboard --logdir), renamed to the cache entry after; and its evaluations looked like the run's."""
    result = run_train(
        tmp_path,
        "agent=sarsa",
        "transfer=on",
        "transfer.pretrain_steps=200",
        "total_steps=200",
        "eval_every=100",
        "eval_episodes=2",
    )
    named = assert_named_paths_exist(result.output, tmp_path)
    assert not [p for p in named if ".tmp" in str(p)]
    lines = result.output.splitlines()
    pretraining = [line for line in lines if "[pretraining source]" in line]
    evals = [line for line in pretraining if "eval step" in line]
    assert len(evals) == 11 and all("- [pretraining source] eval step" in line for line in evals)  # every 20 steps
    done = [line for line in pretraining if "done:" in line]
    assert len(done) == 1 and str(tmp_path / "outputs" / "pretrained") in done[0]
    own = [line for line in lines if "eval step" in line and "[pretraining" not in line]
    assert len(own) == 3  # the run's own: steps 0, 100, 200
