"""Where a ``transfer=on`` run's source checkpoint comes from; this module sits above the trainer.

- ``transfer.source`` is a checkpoint file, or a run directory (then ``transfer.source_agent``);
- unset, a source agent is pretrained on the source task — ``TreasureHunt-v0``, the single-agent MDP
  of the same map — for ``transfer.pretrain_steps`` and cached under
  ``outputs/pretrained/<hash of the source config>/``, so the next run with the same source config
  reuses it. A file lock makes parallel sweep jobs pretrain it once.

Either way the result is a path, which the trainer's warm start (:mod:`dqn_transfer.warm_start`) loads.
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from dqn_transfer.checkpoint import CheckpointError, find_checkpoints, load_agent_checkpoint
from dqn_transfer.config import TrainConfig, TransferConfig, to_plain, validate
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.run_dir import RunDir, agent_file_name
from dqn_transfer.trainer import build_game, train
from dqn_transfer.transfer_mapping import TransferError
from dqn_transfer.warm_start import transfer_targets

log = logging.getLogger("dqn_transfer.transfer")

# The env keys a lone agent's task does not depend on: nobody to talk to or share rewards with, and
# rendering changes nothing learned. Every other env key (a new one included) enters the cache key.
NOT_IN_SOURCE_TASK = ("mode", "reward_mode", "render_mode")


def source_config(config: TrainConfig) -> TrainConfig:
    """The config of the source-task pretraining run: same map and learner, no transfer."""
    pretrain_steps = config.transfer.pretrain_steps
    return dataclasses.replace(
        config,
        transfer=TransferConfig(),
        total_steps=pretrain_steps,
        eval_every=max(1, pretrain_steps // 10),
        checkpoint_every=max(1, pretrain_steps // 4),
        resume=False,
    )


def source_hash(plain: dict[str, Any], layout: str) -> str:
    """Hash of everything that shapes the pretrained source; the map enters by its actual layout."""
    env = {key: plain["env"][key] for key in ENV_KEYS if key not in NOT_IN_SOURCE_TASK}
    env["layout_file"] = None  # the layout text below identifies the map, wherever the file lives
    env["layout"] = layout
    key = {"env": env, "agent": plain["agent"], "seed": plain["seed"],
           "pretrain_steps": plain["transfer"]["pretrain_steps"]}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def pretrained_source(config: TrainConfig, layout: str, launch_dir: Path) -> Path:
    """Pretrain on TreasureHunt-v0 (of the map ``layout``) once per source config; later runs reuse
    the cached checkpoint."""
    # Relative to the launch dir, like transfer.source: the process cwd may be a run dir (chdir, SLURM).
    cache_root = launch_dir / Path(config.transfer.cache_dir or "outputs/pretrained").expanduser()
    run = RunDir(cache_root / source_hash(to_plain(config), layout))
    checkpoint = run.agent_checkpoint(0)
    try:
        run.path.mkdir(parents=True, exist_ok=True)
        lock = open(run.path / ".lock", "w")
    except OSError as err:
        raise TransferError(f"cannot use the pretraining cache {run}: {err.strerror} "
                            "(set transfer.cache_dir to a writable directory)") from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # parallel sweep jobs: the first pretrains, the others wait
        if _is_complete(checkpoint, config.transfer.pretrain_steps):
            log.info("transfer: reusing the pretrained source %s", checkpoint)
            return checkpoint
        pretrain = source_config(config)
        resume = run.has_run()  # a pretraining that was killed
        log.info("transfer: pretraining a source agent on TreasureHunt-v0 for %d steps into %s%s",
                 pretrain.total_steps, run, " (resuming)" if resume else "")
        train(dataclasses.replace(pretrain, resume=resume), run.path, source_task=True)
    return checkpoint


def _is_complete(checkpoint: Path, steps: int) -> bool:
    if not checkpoint.exists():
        return False
    _, meta = load_agent_checkpoint(checkpoint)
    return meta.get("steps") == steps


def resolve_source(transfer: TransferConfig, launch_dir: Path) -> Path:
    """A checkpoint file, or agent ``source_agent`` of a run/checkpoints directory."""
    path = Path(transfer.source).expanduser()
    if not path.is_absolute():
        path = launch_dir / path
    files = find_checkpoints(path)
    if path.is_file():
        return files[0]
    wanted = agent_file_name(transfer.source_agent)
    for file in files:
        if file.name == wanted:
            return file
    raise CheckpointError(f"{path}: has no {wanted} (transfer.source_agent={transfer.source_agent}; "
                          f"found {', '.join(f.name for f in files)})")


def transfer_source(config: TrainConfig, launch_dir: Path) -> Path | None:
    """The checkpoint a run warm-starts from: None without transfer (or when resuming, which has its
    agents already), ``transfer.source`` resolved against ``launch_dir``, else a pretrained source."""
    if not config.transfer.enabled or config.resume:
        return None
    validate(config)
    game = build_game(config)
    transfer_targets(config, game.num_agents)  # refuse bad targets before minutes of pretraining
    if config.transfer.source is not None:
        return resolve_source(config.transfer, launch_dir)
    return pretrained_source(config, game.map.layout, launch_dir)
