"""A multirun job started again in its own directory (submitit requeues a preempted or timed-out SLURM
job that way) continues from its checkpoint; one that never checkpointed starts afresh, cleanly."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra.types import RunMode
from omegaconf import OmegaConf

from dqn_transfer.cli.train import ClaimRunDir, resume_config
from dqn_transfer.config import ConfigError
from dqn_transfer.storage.run_dir import RunDir


def job_start(job_dir: Path) -> ClaimRunDir:
    config = OmegaConf.create(
        {"resume": False, "hydra": {"mode": RunMode.MULTIRUN, "runtime": {"output_dir": str(job_dir)}}}
    )
    callback = ClaimRunDir()
    callback.on_job_start(config)
    return callback


def make_job_dir(tmp_path: Path, checkpointed: bool) -> Path:
    job = tmp_path / "sweep" / "0"
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "config.yaml").write_text("seed: 0\n")  # Hydra's record of this attempt
    (job / "train.log").write_text("this attempt's log\n")
    (job / "metrics.jsonl").write_text('{"step": 0}\n')
    (job / "tb").mkdir()
    (job / "checkpoints").mkdir()
    if checkpointed:
        (job / "checkpoints" / "training_state.safetensors").write_bytes(b"state")
    return job


def test_a_requeued_job_with_a_checkpoint_resumes_and_keeps_everything(tmp_path):
    job = make_job_dir(tmp_path, checkpointed=True)
    try:
        job_start(job)
        assert ClaimRunDir.requeued
        assert sorted(p.name for p in job.iterdir()) == [".hydra", "checkpoints", "metrics.jsonl", "tb", "train.log"]
        assert (job / "checkpoints" / "training_state.safetensors").read_bytes() == b"state"
    finally:
        ClaimRunDir.claim.release()
        ClaimRunDir.requeued = False


def test_a_requeued_job_without_a_checkpoint_starts_afresh(tmp_path):
    job = make_job_dir(tmp_path, checkpointed=False)
    try:
        job_start(job)
        assert not ClaimRunDir.requeued
        # What the earlier attempt left is gone; this attempt's Hydra record and log stay.
        assert sorted(p.name for p in job.iterdir()) == [".hydra", "train.log"]
    finally:
        ClaimRunDir.claim.release()
        ClaimRunDir.requeued = False


def test_an_unreadable_replicas_index_is_one_config_error(tmp_path):
    (tmp_path / "replicas.json").write_text("{not json")
    with pytest.raises(ConfigError, match="replicas.json: its saved config does not fit"):
        resume_config(RunDir(tmp_path), OmegaConf.create({}), [])
