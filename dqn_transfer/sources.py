"""Where a ``transfer=on`` run's source checkpoint comes from; this module sits above the trainer.

- ``transfer.source`` is a checkpoint file, or a run directory (then ``transfer.source_agent``);
- unset, a source agent is pretrained on the source task — ``TreasureHunt-v0``, the single-agent MDP
  of the same map — for ``transfer.pretrain_steps`` and cached under
  ``outputs/pretrained/<hash of the source config>/``, so the next run with the same source config
  reuses it. The entry appears whole or not at all, and a file lock makes parallel sweep jobs
  pretrain it once (:func:`pretrained_sources`).

Either way the result is a path, which the trainer's warm start (:mod:`dqn_transfer.warm_start`) loads.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from dqn_transfer.checkpoint import CheckpointError, find_checkpoints
from dqn_transfer.config import TrainConfig, TransferConfig, replica_configs, to_plain, validate
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.run_cache import RunCache
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


def pretrained_sources(config: TrainConfig, layouts: list[str], launch_dir: Path) -> list[Path]:
    """Pretrain on TreasureHunt-v0 (of each replica's map, ``layouts``) once per source config; later
    runs reuse the cached checkpoints. One source per replica of ``config`` (one for a lone run).

    The cache (:class:`~dqn_transfer.run_cache.RunCache`) holds one entry ``<cache_root>/<hash>/`` per
    source config, whole or not at all, and makes parallel jobs pretrain each source once. When every
    replica's source is missing, they are pretrained together, as one run of replicas (each exactly
    the lone pretraining of its seed and map), and each replica's directory becomes its entry.
    """
    # Relative to the launch dir, like transfer.source: the process cwd may be a run dir (chdir, SLURM).
    cache = RunCache(launch_dir / Path(config.transfer.cache_dir or "outputs/pretrained").expanduser(),
                     "the pretraining cache", "transfer.cache_dir")
    replicas = replica_configs(config)
    keys = [source_hash(to_plain(c), layout) for c, layout in zip(replicas, layouts)]
    steps = config.transfer.pretrain_steps

    def pretrain(indices: list[int], work_dir: Path, resume: bool) -> None:
        pretraining = source_config(config if len(indices) > 1 else replicas[indices[0]])
        what = "a source agent" if len(indices) == 1 else f"{len(indices)} source agents, one per replica,"
        log.info("transfer: pretraining %s on TreasureHunt-v0 for %d steps into %s", what, steps,
                 cache.entry(keys[indices[0]]) if len(indices) == 1 else cache.root)
        train(pretraining, work_dir, source_task=True)

    for i in cache.fill(keys, lambda entry: _reuse(entry, steps), pretrain):
        log.info("transfer: the pretrained source is cached in %s", cache.entry(keys[i]))  # the trainer named the temp dir
    return [cache.entry(key).agent_checkpoint(0) for key in keys]


def _reuse(entry: RunDir, steps: int) -> bool:
    """Whether the cache ``entry`` is complete (pretrained for ``steps``), logged if so."""
    if not RunCache.finished(entry, steps):
        return False
    log.info("transfer: reusing the pretrained source %s", entry.agent_checkpoint(0))
    return True


def resolve_source(transfer: TransferConfig, launch_dir: Path, num_targets: int) -> list[Path]:
    """The checkpoint file of each of the ``num_targets`` target agents: ``transfer.source`` itself if it
    is a file, else agent ``transfer.source_agent`` (one index, or one per target) of a run directory."""
    path = Path(transfer.source).expanduser()
    if not path.is_absolute():
        path = launch_dir / path
    files = find_checkpoints(path)
    wanted = transfer.source_agent
    if path.is_file():
        if not isinstance(wanted, int):
            raise TransferError(f"transfer.source_agent={list(wanted)} picks agents of a run directory, but "
                                f"transfer.source is one agent's file ({path})")
        return files[:1] * num_targets
    replicas = RunDir(path).replica_dirs()
    if replicas:
        raise CheckpointError(f"{path} is a run of {len(replicas)} replicas: pass one replica's directory as "
                              f"transfer.source (e.g. {replicas[0]})")
    per_target = [wanted] * num_targets if isinstance(wanted, int) else list(wanted)
    if len(per_target) != num_targets:
        raise TransferError(f"transfer.source_agent lists {len(per_target)} source agents for {num_targets} target "
                            "agents: give one per target (transfer.targets, default all), or one index for all")
    by_name = {file.name: file for file in files}
    missing = sorted({index for index in per_target if agent_file_name(index) not in by_name})
    if missing:
        raise CheckpointError(f"{path}: has no {', '.join(agent_file_name(i) for i in missing)} "
                              f"(transfer.source_agent={wanted}; found {', '.join(f.name for f in files)})")
    return [by_name[agent_file_name(index)] for index in per_target]


def transfer_sources(config: TrainConfig, launch_dir: Path) -> list[list[Path]] | None:
    """The checkpoint of each target agent of each replica (one list for a lone run): None without
    transfer (or when resuming, which has its agents already), ``transfer.source`` resolved against
    ``launch_dir`` for every replica, else a source pretrained on each replica's own map and seed."""
    if not config.transfer.enabled or config.resume:
        return None
    validate(config)
    replicas = replica_configs(config)
    games = [build_game(c) for c in replicas]
    # Refuse bad targets before minutes of pretraining.
    num_targets = len(transfer_targets(config, games[0].num_agents))
    if config.transfer.source is not None:
        return [resolve_source(config.transfer, launch_dir, num_targets)] * len(replicas)
    if not isinstance(config.transfer.source_agent, int):
        raise TransferError(f"transfer.source_agent={list(config.transfer.source_agent)} picks agents of "
                            "transfer.source; the pretrained source is one agent (set transfer.source)")
    return [[checkpoint] * num_targets
            for checkpoint in pretrained_sources(config, [game.map.layout for game in games], launch_dir)]
