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

import contextlib
import dataclasses
import fcntl
import hashlib
import json
import logging
import os
import secrets
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from dqn_transfer.checkpoint import CheckpointError, find_checkpoints, load_agent_checkpoint
from dqn_transfer.config import TrainConfig, TransferConfig, replica_configs, to_plain, validate
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.run_dir import RunDir, agent_file_name
from dqn_transfer.trainer import build_game, train
from dqn_transfer.transfer_mapping import TransferError
from dqn_transfer.warm_start import transfer_targets

log = logging.getLogger("dqn_transfer.transfer")
T = TypeVar("T")

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

    A cache entry ``<cache_root>/<hash>/`` appears whole or not at all: the pretraining runs in a
    temporary sibling ``.<hash>.tmp-<pid>-<random>/``, renamed into place once complete, and removed
    if the pretraining fails or is interrupted. ``<cache_root>/.<hash>.lock`` (outside the entry, so
    it never moves or disappears under a waiting job) makes parallel jobs pretrain the same source once.
    When every replica's source is missing, they are pretrained together, as one run of replicas (each
    exactly the lone pretraining of its seed and map), and each replica's directory becomes its entry.
    """
    # Relative to the launch dir, like transfer.source: the process cwd may be a run dir (chdir, SLURM).
    cache_root = launch_dir / Path(config.transfer.cache_dir or "outputs/pretrained").expanduser()
    replicas = replica_configs(config)
    keys = [source_hash(to_plain(c), layout) for c, layout in zip(replicas, layouts)]
    entries = [RunDir(cache_root / key) for key in keys]
    checkpoints, steps = [entry.agent_checkpoint(0) for entry in entries], config.transfer.pretrain_steps
    done = [_reuse(checkpoint, steps) for checkpoint in checkpoints]  # complete once it exists: no lock
    if all(done):
        return checkpoints
    with contextlib.ExitStack() as locks:
        # Every lock of the batch, in one fixed order: two jobs never wait for each other in a circle.
        for key, entry in sorted(zip(keys, entries), key=lambda pair: pair[0]):
            locks.enter_context(_cache_lock(cache_root, key, entry))
        missing = [i for i, checkpoint in enumerate(checkpoints)
                   if not (done[i] or _reuse(checkpoint, steps))]  # another job's, pretrained meanwhile
        if not missing:
            return checkpoints
        # Under the locks nobody else pretrains these hashes: what is there was left by a killed
        # pretraining (a temp dir), or is an unfinished entry of the older in-place layout.
        for i in missing:
            for leftover in [*cache_root.glob(f".{keys[i]}.tmp-*"), entries[i].path]:
                _remove(leftover, keys[i])
        if len(missing) == len(replicas) > 1:
            _pretrain(source_config(config), cache_root, keys[0], [entries[i] for i in missing])
        else:
            for i in missing:
                _pretrain(source_config(replicas[i]), cache_root, keys[i], [entries[i]])
    for i in missing:
        log.info("transfer: the pretrained source is cached in %s", entries[i])  # the trainer named the temp dir
    return checkpoints


def _pretrain(config: TrainConfig, cache_root: Path, key: str, entries: list[RunDir]) -> None:
    """Train ``config`` on the source task in a temp dir named after ``key``, then rename its run
    directory (or, for a run of replicas, each replica's) to ``entries``; nothing is left on failure."""
    temp = cache_root / f".{key}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
    what = "a source agent" if len(entries) == 1 else f"{len(entries)} source agents, one per replica,"
    log.info("transfer: pretraining %s on TreasureHunt-v0 for %d steps into %s", what, config.total_steps,
             entries[0] if len(entries) == 1 else cache_root)
    try:
        train(config, temp, source_task=True)
        runs = RunDir(temp).replica_dirs() or [temp]
        for run, entry in zip(runs, entries):
            _cache_call(os.rename, run, entry.path, where=entry)
        _remove(temp, key)
    except BaseException:  # an error, Interrupted, KeyboardInterrupt: leave nothing half-made
        _remove(temp, key)
        raise


@contextlib.contextmanager
def _cache_lock(cache_root: Path, key: str, entry: RunDir) -> Iterator[None]:
    """Hold ``<cache_root>/.<key>.lock`` exclusively. The file is kept: unlinking a lock file lets a
    job that opened it before the unlink lock a file nobody else will ever see."""
    _cache_call(cache_root.mkdir, parents=True, exist_ok=True, where=cache_root)
    with _cache_call(open, cache_root / f".{key}.lock", "a", where=cache_root) as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.info("transfer: waiting for another job pretraining %s", entry)
            fcntl.flock(lock, fcntl.LOCK_EX)
        yield  # closing the file releases the lock


def _cache_call(fn: Callable[..., T], *args: Any, where: Path | RunDir, **kwargs: Any) -> T:
    """``fn(*args, **kwargs)``, with an OSError turned into the cache's one-line TransferError."""
    try:
        return fn(*args, **kwargs)
    except OSError as err:
        raise TransferError(f"cannot use the pretraining cache {where}: {err.strerror} "
                            "(set transfer.cache_dir to a writable directory)") from None


def _remove(path: Path, key: str) -> None:
    """Delete a leftover directory tree of the cache entry ``key``, quietly (it runs while an error or
    an interrupt is on its way up). It is first renamed out of the way: an interrupted pretraining's
    TensorBoard writer appends to its event file by name and could recreate it while rmtree runs; and
    the new name is a temp name, so a removal cut short is cleaned by the next pretraining of ``key``."""
    if not path.exists():
        return
    doomed = path.with_name(f".{key}.tmp-removing-{secrets.token_hex(4)}")
    try:
        path.rename(doomed)
    except OSError:
        doomed = path
    shutil.rmtree(doomed, ignore_errors=True)


def _reuse(checkpoint: Path, steps: int) -> bool:
    """Whether the cache entry of ``checkpoint`` is complete (pretrained for ``steps``), logged if so."""
    if not checkpoint.exists() or load_agent_checkpoint(checkpoint)[1].get("steps") != steps:
        return False
    log.info("transfer: reusing the pretrained source %s", checkpoint)
    return True


def resolve_source(transfer: TransferConfig, launch_dir: Path) -> Path:
    """A checkpoint file, or agent ``source_agent`` of a run/checkpoints directory."""
    path = Path(transfer.source).expanduser()
    if not path.is_absolute():
        path = launch_dir / path
    files = find_checkpoints(path)
    if path.is_file():
        return files[0]
    replicas = RunDir(path).replica_dirs()
    if replicas:
        raise CheckpointError(f"{path} is a run of {len(replicas)} replicas: pass one replica's directory as "
                              f"transfer.source (e.g. {replicas[0]})")
    wanted = agent_file_name(transfer.source_agent)
    for file in files:
        if file.name == wanted:
            return file
    raise CheckpointError(f"{path}: has no {wanted} (transfer.source_agent={transfer.source_agent}; "
                          f"found {', '.join(f.name for f in files)})")


def transfer_sources(config: TrainConfig, launch_dir: Path) -> list[Path] | None:
    """The checkpoint each replica warm-starts from (one for a lone run): None without transfer (or
    when resuming, which has its agents already), ``transfer.source`` resolved against
    ``launch_dir`` for every replica, else a source pretrained on each replica's own map and seed."""
    if not config.transfer.enabled or config.resume:
        return None
    validate(config)
    replicas = replica_configs(config)
    games = [build_game(c) for c in replicas]
    transfer_targets(config, games[0].num_agents)  # refuse bad targets before minutes of pretraining
    if config.transfer.source is not None:
        return [resolve_source(config.transfer, launch_dir)] * len(replicas)
    return pretrained_sources(config, [game.map.layout for game in games], launch_dir)
