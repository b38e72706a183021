"""The loop's cheap costs removed, results unchanged: glibc keeps freed memory, the numpy target sync
and Adam step run in one pass, the last checkpoint is written once, and the evaluation pictures are drawn only where
someone will look (a lone run, not a sweep's job)."""

from __future__ import annotations

import ctypes
import sys

import numpy as np
import pytest
from conftest import read_metrics, without_timing
from hydra.conf import HydraConf
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import OmegaConf
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from dqn_transfer.agents.numpy_dqn import NumpyAdam, NumpyMLP
from dqn_transfer.config import CONFIG_DIR, AgentConfig, ReplicasConfig, TrainConfig
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training import trainer
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import in_multirun, keep_freed_memory, train


def small_config(**overrides) -> TrainConfig:
    env = EnvConfig(size=4, num_treasures=1, num_traps=1, num_agents=2, max_steps=12)
    settings = dict(total_steps=40, eval_every=20, eval_episodes=2, checkpoint_every=20, progress=False)
    settings.update(overrides)
    return TrainConfig(env=env, agent=AgentConfig(algorithm="sarsa"), **settings)  # type: ignore[arg-type]


def test_the_numpy_target_sync_in_place_rounds_as_the_formula_did():
    online = NumpyMLP(6, 5, [16, 16], 3, rngs=[np.random.default_rng(0), np.random.default_rng(1)])
    target = NumpyMLP(6, 5, [16, 16], 3, rngs=[np.random.default_rng(2), np.random.default_rng(3)])
    expected = target.flat.copy()
    noise = np.random.default_rng(4)
    for tau in (0.01, 0.005, 0.3, 0.01):
        expected += np.float32(tau) * (online.flat - expected)  # the formula the sync used to allocate for
        target.update_from(online, tau)
        assert np.array_equal(target.flat.view(np.uint32), expected.view(np.uint32))
        online.flat += noise.standard_normal(online.flat.size).astype(np.float32) * np.float32(1e-3)
    for _ in range(3):  # three syncs toward the same weights, in one pass
        expected += np.float32(0.01) * (online.flat - expected)
    target.update_from(online, 0.01, times=3)
    assert np.array_equal(target.flat.view(np.uint32), expected.view(np.uint32))
    target.update_from(online, 1.0, times=2)
    assert np.array_equal(target.flat, online.flat)


def test_the_numpy_adam_step_rounds_as_torchs_operations_one_by_one():
    # torch.optim.Adam's single-tensor arithmetic, one float32 numpy operation at a time, against the one-pass
    # kernel; gradients from 1e-12 to 10 (subnormal squares), 2,500 parameters (blocks and a remainder).
    rng = np.random.default_rng(0)
    n, lr, beta1, beta2, eps = 2_500, 3e-3, 0.9, 0.999, 1e-8
    param = rng.standard_normal(n).astype(np.float32)
    grad = np.zeros(n, dtype=np.float32)
    adam = NumpyAdam(param.copy(), grad, [(0, 1_000), (1_000, n)], lr=lr)
    exp_avg, exp_avg_sq = np.zeros(n, np.float32), np.zeros(n, np.float32)
    for step in range(1, 13):
        grad[:] = rng.standard_normal(n) * 10.0 ** rng.integers(-12, 2, n)
        exp_avg += (grad - exp_avg) * np.float32(1 - beta1)
        exp_avg_sq *= np.float32(beta2)
        exp_avg_sq += grad * grad * np.float32(1 - beta2)
        denominator = np.sqrt(exp_avg_sq) / np.float32((1 - beta2**step) ** 0.5) + np.float32(eps)
        param += exp_avg / denominator * np.float32(-lr / (1 - beta1**step))
        adam.step([0, 1])
        for ours, theirs in ((adam.flat, param), (adam.exp_avg, exp_avg), (adam.exp_avg_sq, exp_avg_sq)):
            assert np.array_equal(ours.view(np.uint32), theirs.view(np.uint32)), step


def test_glibc_is_told_once_to_keep_freed_memory(monkeypatch):
    monkeypatch.setattr(trainer, "_allocator_tuned", False)
    try:
        ctypes.CDLL("libc.so.6").gnu_get_libc_version  # noqa: B018
        glibc = sys.platform.startswith("linux")
    except (OSError, AttributeError):
        glibc = False
    assert keep_freed_memory() is glibc
    assert keep_freed_memory() is False  # once per process


def test_elsewhere_the_allocator_is_left_alone(monkeypatch):
    monkeypatch.setattr(trainer, "_allocator_tuned", False)
    monkeypatch.setattr(sys, "platform", "darwin")
    assert keep_freed_memory() is False


@pytest.mark.parametrize(
    ("total_steps", "checkpoint_every", "eval_every", "writes"), [(40, 20, 20, 2), (40, 40, 15, 1), (45, 20, 20, 3)]
)
def test_the_last_checkpoint_is_written_once(tmp_path, monkeypatch, total_steps, checkpoint_every, eval_every, writes):
    steps: list[int] = []
    original = trainer.Trainer.save_checkpoint

    def counted(self) -> None:
        steps.append(self.step)
        original(self)

    monkeypatch.setattr(trainer.Trainer, "save_checkpoint", counted)
    written: list[int] = []
    write_all = trainer.atomic_write_all
    monkeypatch.setattr(trainer, "atomic_write_all", lambda files: (written.append(len(files)), write_all(files)))
    config = small_config(total_steps=total_steps, checkpoint_every=checkpoint_every, eval_every=eval_every)
    train(plan_run(config), tmp_path / "run")
    assert len(written) == writes and steps[-1] == total_steps
    assert steps == sorted(set(steps))  # no step written twice
    assert RunDir(tmp_path / "run").training_state.exists()


def images_and_histograms(run_dir) -> tuple[list[str], list[str]]:
    accumulator = EventAccumulator(str(RunDir(run_dir).tensorboard), size_guidance={"images": 0, "histograms": 0})
    accumulator.Reload()
    return accumulator.Tags()["images"], accumulator.Tags()["histograms"]


def test_without_pictures_the_metrics_and_checkpoints_are_the_same(tmp_path):
    for pictures in (True, False):
        train(plan_run(small_config(eval_pictures=pictures)), tmp_path / str(pictures))
    assert images_and_histograms(tmp_path / "True") == (["eval/episode"], ["agent_0/q_values", "agent_1/q_values"])
    assert images_and_histograms(tmp_path / "False") == ([], [])
    assert without_timing(read_metrics(tmp_path / "True")) == without_timing(read_metrics(tmp_path / "False"))
    for name in ("agent_0.safetensors", "agent_1.safetensors"):
        assert (tmp_path / "True" / "checkpoints" / name).read_bytes() == (
            tmp_path / "False" / "checkpoints" / name
        ).read_bytes()


@pytest.fixture
def hydra_mode():
    def set_mode(mode: RunMode) -> None:
        HydraConfig.instance().set_config(OmegaConf.create({"hydra": OmegaConf.structured(HydraConf(mode=mode))}))

    yield set_mode
    HydraConfig.instance().cfg = None  # type: ignore[assignment]


def test_a_sweep_job_draws_no_pictures_unless_asked(tmp_path, hydra_mode):
    assert not in_multirun()  # no Hydra at all: a lone run (the Python API)
    hydra_mode(RunMode.RUN)
    assert not in_multirun()
    train(plan_run(small_config(total_steps=20)), tmp_path / "lone")
    assert images_and_histograms(tmp_path / "lone")[0] == ["eval/episode"]
    hydra_mode(RunMode.MULTIRUN)
    assert in_multirun()
    train(plan_run(small_config(total_steps=20)), tmp_path / "sweep")
    assert images_and_histograms(tmp_path / "sweep") == ([], [])
    train(plan_run(small_config(total_steps=20, eval_pictures=True)), tmp_path / "asked")
    assert images_and_histograms(tmp_path / "asked")[0] == ["eval/episode"]


def test_a_batch_of_replicas_draws_the_first_replicas_pictures_unless_asked(tmp_path):
    train(plan_run(small_config(total_steps=20, replicas=ReplicasConfig(seeds=3))), tmp_path / "default")
    drawn = [images_and_histograms(tmp_path / "default" / f"seed_{s}")[0] for s in range(3)]
    assert drawn == [["eval/episode"], [], []]
    every = small_config(total_steps=20, replicas=ReplicasConfig(seeds=2), eval_pictures=True)
    train(plan_run(every), tmp_path / "all")
    assert [images_and_histograms(tmp_path / "all" / f"seed_{s}")[0] for s in range(2)] == [["eval/episode"]] * 2


def test_the_study_experiments_draw_no_pictures():
    experiments = sorted((CONFIG_DIR / "experiment").glob("*.yaml"))
    assert experiments  # the folder is there: a moved one would make this test pass on nothing
    for path in experiments:
        config = OmegaConf.load(path)
        if "total_steps" in config:  # a whole experiment (the others extend one)
            assert config.eval_pictures is False, path.name
