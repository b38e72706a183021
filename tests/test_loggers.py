"""``logger=[tensorboard,csv,wandb]``: the CSV backend holds exactly TensorBoard's scalars (and a
resumed run continues it without duplicates); Weights & Biases, offline, writes the local run of each
replica (one group) with the config, the scalars and the evaluation pictures, and a resumed replica as
a new run of the group whose history is the CSV's after the checkpoint. No server is contacted.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import run_train, start_train
from omegaconf import OmegaConf
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from test_run_safety import LONG_RUN as SIGNALLED_RUN
from test_run_safety import MAP, wait_for_evaluations

from dqn_transfer.config import AgentConfig, ReplicasConfig, TrainConfig
from dqn_transfer.config.schema import ConfigError, validate
from dqn_transfer.enums import Algorithm, Logger
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.storage.checkpoint import load_training_state
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.loggers import PendingRows, RunLoggers, import_wandb
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer, train


def config(logger: list[str], resume: bool = False, **overrides) -> TrainConfig:
    settings = dict(
        env=EnvConfig(layout=MAP),
        agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.1),
        seed=2,
        total_steps=600,
        eval_every=100,
        eval_episodes=1,
        checkpoint_every=200,  # with the training points' window (LOG_EVERY)
        progress=False,
        resume=resume,
        logger=[Logger(name) for name in logger],
    )
    return TrainConfig(**{**settings, **overrides})


def csv_points(run: RunDir) -> list[tuple[int, str, float]]:
    with run.scalars_csv.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["step", "tag", "value"]
    return [(int(step), tag, float(value)) for step, tag, value in rows[1:]]


def tensorboard_points(run: RunDir) -> list[tuple[int, str, float]]:
    accumulator = EventAccumulator(str(run.tensorboard), size_guidance={"scalars": 0})
    accumulator.Reload()
    return [(e.step, tag, e.value) for tag in accumulator.Tags()["scalars"] for e in accumulator.Scalars(tag)]


def as_float32(points: list[tuple[int, str, float]]) -> list[tuple[int, str, float]]:
    """TensorBoard keeps float32 values; the CSV the full float."""
    return sorted((step, tag, float(np.float32(value))) for step, tag, value in points)


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_csv_rows_are_the_tensorboard_scalars(tmp_path):
    train(plan_run(config(["tensorboard", "csv"])), tmp_path / "run")
    run = RunDir(tmp_path / "run")
    rows = csv_points(run)
    assert {tag for _, tag, _ in rows} >= {"eval/team_return", "team/return", "agent_1/episodic_return", "train/sps"}
    assert as_float32(rows) == as_float32(tensorboard_points(run))
    assert len({(step, tag) for step, tag, _ in rows}) == len(rows)


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_default_run_writes_tensorboard_only(tmp_path):
    train(plan_run(config(["tensorboard"], total_steps=50)), tmp_path / "run")
    run = RunDir(tmp_path / "run")
    assert run.tensorboard.is_dir() and not run.scalars_csv.exists() and not run.wandb.exists()
    assert TrainConfig().logger == [Logger.tensorboard]


def test_csv_only_run_and_an_empty_list(tmp_path):
    with pytest.raises(ConfigError, match="logger must name at least one of tensorboard, csv, wandb"):
        validate(config([]))
    train(plan_run(config(["csv"], total_steps=50, env=EnvConfig())), tmp_path / "run")
    run = RunDir(tmp_path / "run")
    assert run.scalars_csv.exists() and not run.tensorboard.exists()


def test_wandb_missing_is_one_clear_message(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb fails, as without the package
    with pytest.raises(ConfigError, match=r"^logger=\[...,wandb\] needs the wandb package: pip install"):
        validate(config(["tensorboard", "wandb"]))
    with pytest.raises(ImportError, match="needs the wandb package"):
        import_wandb()


class _Killed(Exception):
    """Stands in for SIGKILL."""


def killed_before_checkpoint(monkeypatch, loggers: list[str], run_dir: Path) -> None:
    """Train ``config(loggers)`` into ``run_dir`` and die right before the checkpoint at step 400 (the last
    one written is at 200), as a SIGKILL there would."""
    original = Trainer.save_checkpoint

    def die_at_400(self):
        if self.step == 400:
            raise _Killed
        original(self)

    with monkeypatch.context() as patched:
        patched.setattr(Trainer, "save_checkpoint", die_at_400)
        with pytest.raises(_Killed):
            train(plan_run(config(loggers)), run_dir)


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_resumed_run_continues_the_csv_without_duplicates(tmp_path, monkeypatch):
    """Die right before the checkpoint at step 400: the rows of steps 201..400 are in the CSV, the
    checkpoint at 200 does not know them; the resumed run logs them again, once."""
    loggers = ["tensorboard", "csv"]
    train(plan_run(config(loggers)), tmp_path / "reference")
    killed_before_checkpoint(monkeypatch, loggers, tmp_path / "killed")
    killed = RunDir(tmp_path / "killed")
    assert max(step for step, _, _ in csv_points(killed)) > 200  # logged after the last checkpoint
    train(plan_run(config(loggers, resume=True)), tmp_path / "killed")

    rows = csv_points(killed)
    assert len({(step, tag) for step, tag, _ in rows}) == len(rows)  # no duplicates
    assert as_float32(rows) == as_float32(tensorboard_points(killed))
    # the same points as the uninterrupted run (but for the speed)
    not_speed = lambda points: [p for p in points if p[1] != "train/sps"]  # noqa: E731
    assert sorted(not_speed(rows)) == sorted(not_speed(csv_points(RunDir(tmp_path / "reference"))))


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_what_a_checkpoint_covers_is_on_the_disk_before_the_checkpoint(tmp_path, monkeypatch):
    """The episodes' points wait in memory between log intervals; at each checkpoint (steps 200, 400
    and the end, 600), before its resume state replaces the last one, the CSV and the event file hold
    every point up to its step and are fsync'ed: a run killed (or a machine that crashed) right after
    the checkpoint resumes with no gap in its logs."""
    run = RunDir(tmp_path / "run")
    fsync, replace = os.fsync, os.replace
    synced: set[int] = set()  # the inodes fsync'ed since the last resume state
    at_checkpoints: list[tuple[set[int], list, list]] = []

    def recorded_fsync(fd: int) -> None:
        synced.add(os.fstat(fd).st_ino)
        fsync(fd)

    def recorded_replace(source, target) -> None:
        if Path(target) == run.training_state:
            at_checkpoints.append((set(synced), csv_points(run), tensorboard_points(run)))
            synced.clear()
        replace(source, target)

    monkeypatch.setattr(os, "fsync", recorded_fsync)
    monkeypatch.setattr(os, "replace", recorded_replace)
    train(plan_run(config(["tensorboard", "csv"])), run.path)
    monkeypatch.undo()

    logs = {run.scalars_csv.stat().st_ino, next(run.tensorboard.iterdir()).stat().st_ino}
    rows, points = csv_points(run), tensorboard_points(run)
    assert len(at_checkpoints) == 3
    for step, (synced_then, rows_then, points_then) in zip((200, 400, 600), at_checkpoints):
        assert logs <= synced_then, step
        assert rows_then == [row for row in rows if row[0] <= step]
        assert sorted(points_then) == sorted(point for point in points if point[0] <= step)
    assert any(tag == "team/return" and step > 400 for step, tag, _ in rows)  # episodes ended after 400 too


class CallsInOrder:
    """A backend that records what it is handed, in order: ``(call, steps)``."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, list[int]]] = []

    def scalars(self, points, step):
        self.calls.append(("scalars", [step]))

    def scalar_rows(self, tags, steps, values, wall_times):
        self.calls.append(("rows", steps.tolist()))
        self.rows = dict(zip(steps.tolist(), values.tolist()))

    def evaluation_views(self, picture, q_values, step):
        self.calls.append(("views", [step]))

    def text(self, tag, text, step=0):
        self.calls.append(("text", [step]))

    def flush(self, durable=False):
        self.calls.append(("flush", [durable]))

    def close(self):
        self.calls.append(("close", []))


def test_episodes_reach_the_backends_in_one_batch_and_before_any_later_point(tmp_path):
    """Episodes' points wait until a flush or another point comes: then they go first, in one batch, so
    every backend sees the steps in order (W&B drops a point at a step it has passed)."""
    game = plan_run(config(["csv"], env=EnvConfig(num_agents=2))).replicas[0].new_game()
    loggers = RunLoggers([], RunDir(tmp_path), "group", game, {}, resume=False)
    backend = CallsInOrder()
    loggers.backends.append(backend)
    assert loggers.episode_tags == [
        "agent_0/episodic_return",
        "agent_1/episodic_return",
        "agent_0/episodic_length",
        "agent_1/episodic_length",
        "team/return",
        "team/treasures_collected",
        "team/trap_rate",
    ]
    for step in (3, 5, 8):
        loggers.episode(step, np.arange(7.0) + step)
    assert backend.calls == []
    loggers.scalar("team/exchange_best_agent", 1, 8)
    loggers.episode(11, np.arange(7.0))
    loggers.flush()
    loggers.flush(durable=True)
    loggers.episode(12, np.arange(7.0))
    loggers.close()
    assert backend.calls == [
        ("rows", [3, 5, 8]),
        ("scalars", [8]),
        ("rows", [11]),
        ("flush", [False]),
        ("flush", [True]),
        ("rows", [12]),
        ("close", []),
    ]


def test_pending_rows_grow_and_keep_every_row(tmp_path):
    pending = PendingRows(2)
    for step in range(150):  # beyond the first arrays' room
        pending.add(step, np.array([step, -step]))
    steps, wall_times, values = pending.take()
    assert steps.tolist() == list(range(150))
    assert values.tolist() == [[step, -step] for step in range(150)]
    assert np.all(np.diff(wall_times) >= 0)
    assert pending.take()[0].size == 0


# ------------------------------------------------------------------------ Weights & Biases, offline


def wandb_records(path: Path):
    """The records of a ``run-*.wandb`` file: after a 7-byte header, LevelDB-log blocks of 32 KiB whose
    chunks (7-byte header: CRC, length, type full/first/middle/last) make up the protobuf records."""
    from wandb.proto import wandb_internal_pb2

    data, block = path.read_bytes(), 32768
    assert data[:4] == b":W&B"
    pos, record = 7, b""
    while pos + 7 <= len(data):
        left = block - pos % block
        _crc, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        if left < 7 or (length == 0 and kind == 0):
            pos += left
            continue
        chunk = data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        record = chunk if kind in (1, 2) else record + chunk
        if kind in (1, 4):
            parsed = wandb_internal_pb2.Record()
            parsed.ParseFromString(record)
            yield parsed


@pytest.fixture
def wandb_offline(tmp_path, monkeypatch):
    wandb = pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path / "wandb_dir"))
    monkeypatch.delenv("WANDB_SILENT", raising=False)  # quiet by the run's own setting, not the environment's
    monkeypatch.delenv("WANDB_PROJECT", raising=False)
    yield
    wandb.teardown()  # the W&B service process this test started


def wandb_run(offline: Path):
    """An offline W&B run directory's header (the ``run`` record), its scalar points ``(step, tag,
    value)`` and the steps of its evaluation pictures."""
    records = list(wandb_records(next(offline.glob("run-*.wandb"))))
    header = next(r.run for r in records if r.WhichOneof("record_type") == "run")
    points, pictures = [], []
    for history in (r.history for r in records if r.WhichOneof("record_type") == "history"):
        items = {"/".join(item.nested_key) or item.key: json.loads(item.value_json) for item in history.item}
        step = items["_step"]
        scalars = {"/".join(item.nested_key) or item.key for item in history.item if len(item.nested_key) <= 1}
        points += [(step, k, float(items[k])) for k in scalars if not k.startswith("_")]
        if "eval/episode/path" in items:
            pictures.append(step)
            assert (offline / "files" / items["eval/episode/path"]).is_file()
    return header, sorted(points), pictures


def wandb_runs(run: RunDir) -> list:
    """:func:`wandb_run` of each W&B run of a replica, in the order of ``wandb/wandb_id`` (oldest first)."""
    # A finished run's records may still be on their way to its file (the W&B service writes them, late on a
    # loaded machine): the service's teardown waits until they are all written.
    pytest.importorskip("wandb").teardown()
    ids = run.wandb_id.read_text().split()
    by_id = {offline.name.rsplit("-", 1)[1]: offline for offline in run.wandb.glob("offline-run-*")}
    assert sorted(by_id) == sorted(ids)  # one offline run directory per W&B run
    return [wandb_run(by_id[run_id]) for run_id in ids]


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore")
def test_wandb_offline_writes_each_replica_as_a_run_of_one_group(tmp_path, wandb_offline):
    batch = tmp_path / "batch"
    train(plan_run(config(["csv", "wandb"], env=EnvConfig(), replicas=ReplicasConfig(seeds=2))), batch)
    names = json.loads((batch / "replicas.json").read_text())["replicas"]
    assert len(names) == 2
    for name in names:
        run = RunDir(batch / name)
        ((header, points, pictures),) = wandb_runs(run)
        assert (header.run_group, header.display_name, header.project) == ("batch", name, "dqn_transfer")
        logged = {item.key: json.loads(item.value_json) for item in header.config.update}
        assert logged["agent"]["algorithm"] == "qlearning" and logged["logger"] == ["csv", "wandb"]
        assert logged["seed"] == OmegaConf.load(run.config).seed  # the replica's own config
        assert points == sorted(csv_points(run))  # the scalars' history, value for value
        # an evaluation picture at every evaluation, of the first replica (eval_pictures' default)
        assert pictures == (list(range(0, 601, 100)) if name == names[0] else [])


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore")
def test_a_resumed_run_is_a_new_wandb_run_whose_history_is_the_csv_after_the_checkpoint(
    tmp_path, monkeypatch, wandb_offline
):
    """Killed right before the checkpoint at step 400 (the last one at 200): the killed W&B run keeps
    all it logged, up to step 400; the resumed replica is a new W&B run of the group, ``run-resumed-1``,
    whose history is the CSV's rows after step 200 (which the resumed run logged again), value for
    value; together up to 200 and after it they are the run's scalars."""
    loggers = ["csv", "wandb"]
    killed_before_checkpoint(monkeypatch, loggers, tmp_path / "run")
    run = RunDir(tmp_path / "run")
    killed_rows = sorted(csv_points(run))
    assert max(step for step, _, _ in killed_rows) == 400
    train(plan_run(config(loggers, resume=True)), tmp_path / "run")

    rows = sorted(csv_points(run))
    (killed, killed_points, _), (resumed, resumed_points, resumed_pictures) = wandb_runs(run)
    assert (killed.display_name, resumed.display_name) == ("run", "run-resumed-1")
    assert killed.run_group == resumed.run_group == "run" and killed.run_id != resumed.run_id
    assert resumed.notes == f"resumed from a checkpoint: logs from step 201 on, after W&B run {killed.run_id}"
    assert killed_points == killed_rows  # everything the killed run logged, after its checkpoint too
    assert resumed_points == [p for p in rows if p[0] > 200]
    assert [p for p in killed_points if p[0] <= 200] + resumed_points == rows
    assert resumed_pictures == [300, 400, 500, 600]


@pytest.mark.slow
def test_wandb_adds_no_console_line_and_keeps_its_files(tmp_path, wandb_offline):
    """W&B's banners, history and summary (68 of a 2-replica run's 73 lines before) stay off the console."""
    (tmp_path / "map.txt").write_text(MAP)
    run = ("env.layout_file=map.txt", "replicas.seeds=2", "total_steps=200", "eval_every=100", "eval_episodes=1")
    run = (*run, "replicas.workers=1")  # one process's lines, whatever the cores
    without = run_train(tmp_path, *run, "logger=[csv]", run_dir=tmp_path / "csv")
    with_wandb = run_train(tmp_path, *run, "logger=[csv,wandb]", run_dir=tmp_path / "wandb")
    lines = with_wandb.output.splitlines()
    assert len(lines) == len(without.output.splitlines()) == 5  # run directory, 3 evaluations, done
    assert not [line for line in lines if "wandb:" in line]
    for seed in (0, 1):
        ((_, points, _),) = wandb_runs(RunDir(tmp_path / "wandb" / f"seed_{seed}"))
        assert points == sorted(csv_points(RunDir(tmp_path / "wandb" / f"seed_{seed}")))


LONG_RUN = (*SIGNALLED_RUN, "logger=[csv,wandb]")  # long enough to be signalled while it learns


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_run_stopped_by_a_signal_and_resumed_splits_its_wandb_history_at_the_checkpoint(
    tmp_path, wandb_offline, signum
):
    """``python train.py`` stopped by a signal checkpoints at the step it reached, S: its W&B run holds
    the CSV's rows up to S, and the resumed run's new W&B run the rows after S, nothing twice."""
    (tmp_path / "map.txt").write_text(MAP)
    run_dir = tmp_path / "run"
    proc = start_train(tmp_path, *LONG_RUN, run_dir=run_dir)
    wait_for_evaluations(run_dir, 3, proc)
    proc.send_signal(signum)
    assert proc.wait(timeout=60) == 128 + signum
    run = RunDir(run_dir)
    stopped = load_training_state(run.checkpoints / "training_state.safetensors")[1]["counters"]["step"]
    assert 200 <= max(step for step, _, _ in csv_points(run)) <= stopped < 1500
    run_train(tmp_path, "resume=true", run_dir=run_dir)

    rows = sorted(csv_points(run))
    (first, first_points, _), (resumed, resumed_points, _) = wandb_runs(run)
    assert (first.display_name, resumed.display_name) == ("run", "run-resumed-1")
    # A signal that lands in the evaluation at S leaves it unrecorded; the resumed run plays it again, whole.
    assert sorted(first_points + resumed_points) == rows  # nothing lost, nothing twice
    assert all(p[0] <= stopped for p in first_points) and all(p[0] >= stopped for p in resumed_points)
    # Step S itself may be in both: the first run's training scalars at S, the replayed evaluation's at S.
    assert all(tag.startswith("eval/") for step, tag, _ in resumed_points if step == stopped)
    assert not ({p[:2] for p in first_points} & {p[:2] for p in resumed_points})
    assert resumed.notes == f"resumed from a checkpoint: logs from step {stopped + 1} on, after W&B run {first.run_id}"
