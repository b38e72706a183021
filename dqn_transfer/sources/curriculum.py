"""A curriculum: stages trained one after another, each warm-starting the next; the run is the last.

``curriculum.stages`` (a ``conf/curriculum/`` option) lists the stages before the run, easiest first.
Stage ``n`` is the run's own config with its env changed by the stage's ``env``, trained for the
stage's ``steps``. Every stage after the first starts from the previous stage's agents through the
transfer hook (the previous map placed at the stage's ``offset``, its agents picked by the stage's
``source_agent``), with the run's other ``transfer.*`` settings; the run starts from the last stage
at ``transfer.offset``. With replicas, every replica has its own chain of stages (its seed, its map).

Finished stages are cached like the pretrained sources (:class:`~dqn_transfer.sources.run_cache.RunCache`,
``<launch dir>/outputs/curriculum/<hash>/``, each an ordinary run directory). A stage's hash covers
its config and its predecessor's hash, so every run whose curriculum begins the same way reuses those
stages, and a changed stage retrains itself and what follows. The cache is resumable: a stage that was
interrupted or killed continues from its last checkpoint when the command runs again.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
from pathlib import Path

from dqn_transfer.config import TrainConfig, TransferConfig, to_plain
from dqn_transfer.envs.settings import MAP_CHOICE_KEYS
from dqn_transfer.sources.resolve import resolve_source
from dqn_transfer.sources.run_cache import RunCache
from dqn_transfer.training.plan import RunPlan, describe_stage
from dqn_transfer.training.workers import train_on_cores

log = logging.getLogger("dqn_transfer.sources.curriculum")

# Keys that change how a run is watched, not what it learns: left out of a stage's hash.
NOT_IN_STAGE_HASH = ("progress", "resume", "eval_pictures", "objective", "logger")
# transfer.* keys a curriculum refuses (at their defaults in every stage), left out of a stage's hash so
# that the stages cached before they existed stay valid.
NOT_IN_STAGE_TRANSFER_HASH = ("source_task", "source_map_shift", "chest_aware")
# env.* keys of other games (a curriculum is refused there), and those that only choose the map (its
# layout is in the hash), likewise left out.
NOT_IN_STAGE_ENV_HASH = ("factory", "kwargs", *MAP_CHOICE_KEYS)


def stage_hash(config: TrainConfig, layout: str, previous: str | None) -> str:
    """Hash of everything that shapes a stage's run: its config (the map by its actual ``layout``) and
    the hash of the stage it starts from."""
    plain = {key: value for key, value in to_plain(config).items() if key not in NOT_IN_STAGE_HASH}
    env = {key: value for key, value in plain["env"].items() if key not in NOT_IN_STAGE_ENV_HASH}
    plain["env"] = {**env, "layout_file": None, "layout": layout}
    # replicas.workers: how the replicas are spread over processes, not what they learn (same bits)
    plain["replicas"] = {key: value for key, value in plain["replicas"].items() if key != "workers"}
    plain["transfer"] = {
        key: value for key, value in plain["transfer"].items() if key not in NOT_IN_STAGE_TRANSFER_HASH
    }
    if plain["transfer"].get("source_agent") is None:
        # Only the first stage's (it starts from nothing): hashed as the 0 it was before the default became
        # null, so that the stages cached before stay valid.
        plain["transfer"]["source_agent"] = 0
    key = {"config": plain, "previous": previous}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def curriculum_sources(plan: RunPlan, launch_dir: Path) -> list[list[Path]] | None:
    """Train (or reuse) every stage before the run (the plan's chain), for every replica; returns the
    checkpoints each target agent of each replica starts from (None when resuming: the run has its
    agents already)."""
    config = plan.config
    if config.resume:
        return None
    stages = config.curriculum.stages
    cache = RunCache(
        launch_dir / Path(config.curriculum.cache_dir or "outputs/curriculum").expanduser(),
        "the curriculum cache",
        "curriculum.cache_dir",
        resumable=True,
    )
    keys: list[str | None] = [None] * len(plan.replicas)  # a stage's hashes, and before the first none
    previous: list[Path] | None = None
    for n, (stage, staged) in enumerate(zip(stages, plan.chain)):
        keys = [stage_hash(replica.config, replica.identity, key) for replica, key in zip(staged.replicas, keys)]
        sources = (
            None
            if previous is None
            else [
                resolve_source(
                    TransferConfig(source=str(run), source_agent=stage.source_agent), launch_dir, staged.num_agents
                )
                for run in previous
            ]
        )

        label = f"stage {n + 1} of {len(stages) + 1} ({describe_stage(stage.env)})"
        hashes = [key for key in keys if key is not None]
        entries = [cache.entry(key).path for key in hashes]
        trained = cache.fill(
            hashes,
            functools.partial(RunCache.finished, steps=stage.steps),
            functools.partial(
                _train_stage, label, f"[curriculum stage {n + 1}/{len(stages) + 1}]", staged, sources, entries
            ),
        )
        previous = [cache.entry(key).path for key in hashes]
        for i, run in enumerate(previous):
            log.info("curriculum: %s %s %s", label, "trained into" if i in trained else "reused from", run)
    assert previous is not None  # a curriculum has stages
    return [
        resolve_source(dataclasses.replace(config.transfer, source=str(run)), launch_dir, len(plan.targets))
        for run in previous
    ]


def _train_stage(
    label: str,
    tag: str,
    staged: RunPlan,
    sources: list[list[Path]] | None,
    entries: list[Path],
    indices: list[int],
    work_dir: Path,
    resume: bool,
) -> None:
    """Train (or resume) a stage's replicas ``indices`` (all of ``staged``'s, or one) into ``work_dir``,
    which the cache then renames to their ``entries``: the paths the lines name, ``tag`` before those of
    the stage's run."""
    run = staged if len(indices) > 1 else staged.lone(indices[0])
    final_dirs = [entries[i] for i in indices]
    log.info(
        "curriculum: %s %s, %d steps%s, into %s",
        "resuming" if resume else "training",
        label,
        run.config.total_steps,
        f" for {len(indices)} replicas" if len(indices) > 1 else "",
        ", ".join(map(str, final_dirs)),
    )
    train_on_cores(
        run.resuming(resume),
        work_dir,
        sources=None if resume or sources is None else [sources[i] for i in indices],
        tag=tag,
        final_dirs=final_dirs,
    )
