"""Where a ``transfer=on`` run's source checkpoint comes from; this module sits above the trainer.

- ``transfer.source`` is a checkpoint file, or a run directory (then ``transfer.source_agent``); a run
  of replicas gives each replica of a run of replicas the source replica of the same name (its seed);
- unset, a source is pretrained for ``transfer.pretrain_steps`` on ``transfer.source_task``:
  ``single``, ``TreasureHunt-v0`` (the single-agent MDP of the map), ``per_agent``, ``TreasureHunt-v0``
  from each target agent's own start (one source per target), or ``team``, the run's own
  multi-agent game, whose member ``transfer.source_agent`` each target starts from; on the run's map,
  or on the generated map ``transfer.source_map_shift`` map seeds further. It is cached under
  ``outputs/pretrained/<hash of the source config>/``, so the next run with the same source config
  reuses it. The entry appears whole or not at all, and a file lock makes parallel sweep jobs
  pretrain it once (:func:`pretrained_sources`).

Either way the result is a path, which the trainer's warm start (:mod:`dqn_transfer.transfer.warm_start`) loads.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dqn_transfer.config import TransferConfig, to_plain
from dqn_transfer.enums import Mode, SourceTask
from dqn_transfer.envs.settings import ENV_KEYS, MAP_CHOICE_KEYS
from dqn_transfer.sources.run_cache import RunCache
from dqn_transfer.storage.checkpoint import CheckpointError, find_checkpoints
from dqn_transfer.storage.run_dir import RunDir, agent_file_name
from dqn_transfer.training.plan import RunPlan, source_map
from dqn_transfer.training.workers import train_on_cores
from dqn_transfer.transfer.mapping import TransferError

log = logging.getLogger("dqn_transfer.transfer")

# The env keys a lone agent's task does not depend on: nobody to talk to or share rewards with, and
# rendering changes nothing learned. Every other env key (a new one included) enters the cache key.
NOT_IN_SOURCE_TASK = ("mode", "reward_mode", "render_mode")
# A team source plays the run's own game (``transfer.source_task=team``): only rendering is left out.
NOT_IN_TEAM_TASK = ("render_mode",)
# The source agent of every target when transfer.source_agent is unset and the source is no team of the run's size.
DEFAULT_SOURCE_AGENT = 0
# Before every line the source's pretraining logs (its evaluations look like the run's own otherwise).
PRETRAINING_TAG = "[pretraining source]"


def source_hash(plain: dict[str, Any], layout: str, task: SourceTask | str = SourceTask.single) -> str:
    """Hash of everything that shapes the pretrained source; the map enters by its actual layout.

    ``plain`` is the run's config on the source's map (:func:`source_map`), as JSON data. A ``single``
    source's key is what it has always been, so existing cache entries stay valid; a ``per_agent``
    source's is a ``single`` source's on its map with its start first (the ``layout``); a ``team``
    source's key names its task and keeps the env keys a team depends on (mode, reward_mode)."""
    team = SourceTask(task) is SourceTask.team
    left_out = NOT_IN_TEAM_TASK if team else NOT_IN_SOURCE_TASK
    env = {key: plain["env"][key] for key in ENV_KEYS if key not in left_out and key not in MAP_CHOICE_KEYS}
    env["layout_file"] = None  # the layout text below identifies the map, wherever the file lives
    env["layout"] = layout
    key = {
        "env": env,
        "agent": plain["agent"],
        "seed": plain["seed"],
        "pretrain_steps": plain["transfer"]["pretrain_steps"],
    }
    if team:
        key["source_task"] = SourceTask.team.value
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def pretrained_sources(plan: RunPlan, pretraining: RunPlan, launch_dir: Path) -> list[RunDir]:
    """Pretrain ``pretraining`` (a run of ``plan``'s chain, on ``transfer.source_task`` of each replica's
    source map) once per source config; later runs reuse the cached runs. One source per replica of
    ``plan`` (one for a lone run): the run directory of its cache entry, whose ``agent_0.safetensors``
    is the single-agent source and whose agent files are the team source.

    A ``per_agent`` source's map has the start of its agent as agent 0's (the two start digits swapped),
    so its layout, and with it its key, names the start: agent 0's source is the ``single`` source.

    The cache (:class:`~dqn_transfer.sources.run_cache.RunCache`) holds one entry ``<cache_root>/<hash>/`` per
    source config, whole or not at all, and makes parallel jobs pretrain each source once. When every
    replica's source is missing, they are pretrained together, as one run of replicas (each exactly
    the lone pretraining of its seed and map), and each replica's directory becomes its entry.
    """
    config = plan.config
    # Relative to the launch dir, like transfer.source: the process cwd may be a run dir (chdir, SLURM).
    cache = RunCache(
        launch_dir / Path(config.transfer.cache_dir or "outputs/pretrained").expanduser(),
        "the pretraining cache",
        "transfer.cache_dir",
    )
    task = SourceTask(config.transfer.source_task)
    keys = [
        source_hash(to_plain(source_map(replica.config)), source.identity, task)
        for replica, source in zip(plan.replicas, pretraining.replicas)
    ]
    steps = config.transfer.pretrain_steps
    shift = config.transfer.source_map_shift

    def pretrain(indices: list[int], work_dir: Path, resume: bool) -> None:
        run = pretraining if len(indices) > 1 else pretraining.lone(indices[0])
        where = cache.entry(keys[indices[0]]) if len(indices) == 1 else cache.root
        on_map = (
            f" on map seed {run.config.env.map_seed} (env.map_seed {'+' if shift > 0 else '-'} {abs(shift)})"
            if shift
            else ""
        )
        if task is SourceTask.team:
            what = "a source team" if len(indices) == 1 else f"{len(indices)} source teams, one per replica,"
            log.info(
                "transfer: pretraining %s on this run's game%s (mode %s) for %d steps into %s",
                what,
                on_map,
                Mode(run.config.env.mode).value,
                steps,
                where,
            )
        else:
            what = "a source agent" if len(indices) == 1 else f"{len(indices)} source agents, one per replica,"
            log.info("transfer: pretraining %s on TreasureHunt-v0%s for %d steps into %s", what, on_map, steps, where)
        # The run is trained in a work directory the cache renames to the entry: its lines name the entry.
        train_on_cores(run, work_dir, tag=PRETRAINING_TAG, final_dirs=[cache.entry(keys[i]).path for i in indices])

    for i in cache.fill(keys, lambda entry: _reuse(entry, steps), pretrain):
        log.info("transfer: the pretrained source is cached in %s", cache.entry(keys[i]))
    return [cache.entry(key) for key in keys]


def _reuse(entry: RunDir, steps: int) -> bool:
    """Whether the cache ``entry`` is complete (pretrained for ``steps``), logged if so."""
    if not RunCache.finished(entry, steps):
        return False
    log.info("transfer: reusing the pretrained source %s", entry.agent_checkpoint(0))
    return True


def source_agents(transfer: TransferConfig, num_targets: int) -> list[int]:
    """``transfer.source_agent`` as one source agent index per target agent: one index for every target,
    or a list with one per target (refused if its length is not ``num_targets``); unset, agent 0."""
    wanted = DEFAULT_SOURCE_AGENT if transfer.source_agent is None else transfer.source_agent
    per_target = [wanted] * num_targets if isinstance(wanted, int) else list(wanted)
    if len(per_target) != num_targets:
        raise TransferError(
            f"transfer.source_agent lists {len(per_target)} source agents for {num_targets} target "
            "agents: give one per target (transfer.targets, default all), or one index for all"
        )
    return per_target


def team_members(transfer: TransferConfig, num_agents: int, num_targets: int) -> list[int]:
    """The member of a pretrained source team each target agent starts from (``transfer.source_agent``:
    one index for every target, or one per target), checked against the team's ``num_agents``."""
    wanted = DEFAULT_SOURCE_AGENT if transfer.source_agent is None else transfer.source_agent
    per_target = source_agents(transfer, num_targets)
    bad = sorted({index for index in per_target if index >= num_agents})
    if bad:
        raise TransferError(
            f"transfer.source_agent={wanted if isinstance(wanted, int) else list(wanted)}: the "
            f"source team (transfer.source_task=team) is this run's team of {num_agents} agents "
            f"(0..{num_agents - 1}), which has no agent {', '.join(map(str, bad))}"
        )
    return per_target


def source_path(transfer: TransferConfig, launch_dir: Path) -> Path:
    """``transfer.source`` as a path, a relative one taken from ``launch_dir``.

    :param transfer: the run's transfer config (its ``source`` set).
    :param launch_dir: the directory the run was launched from.
    """
    path = Path(str(transfer.source)).expanduser()
    return path if path.is_absolute() else launch_dir / path


def resolve_source(transfer: TransferConfig, launch_dir: Path, num_targets: int) -> list[Path]:
    """The checkpoint file of each of the ``num_targets`` target agents: ``transfer.source`` itself if it
    is a file, else agent ``transfer.source_agent`` (one index, or one per target) of a run directory."""
    path = source_path(transfer, launch_dir)
    files = find_checkpoints(path)
    wanted = DEFAULT_SOURCE_AGENT if transfer.source_agent is None else transfer.source_agent
    if path.is_file():
        if not isinstance(wanted, int):
            raise TransferError(
                f"transfer.source_agent={list(wanted)} picks agents of a run directory, but "
                f"transfer.source is one agent's file ({path})"
            )
        return files[:1] * num_targets
    replicas = RunDir(path).replica_dirs()
    if replicas:
        raise CheckpointError(
            f"{path} is a run of {len(replicas)} replicas: pass one replica's directory as "
            f"transfer.source (e.g. {replicas[0]})"
        )
    per_target = source_agents(transfer, num_targets)
    by_name = {file.name: file for file in files}
    missing = sorted({index for index in per_target if agent_file_name(index) not in by_name})
    if missing:
        raise CheckpointError(
            f"{path}: has no {', '.join(agent_file_name(i) for i in missing)} "
            f"(transfer.source_agent={wanted}; found {', '.join(f.name for f in files)})"
        )
    return [by_name[agent_file_name(index)] for index in per_target]


def team_to_team(transfer: TransferConfig, source: Path, targets: Sequence[int], num_agents: int) -> TransferConfig:
    """``transfer`` for the source ``source``: with ``source_agent`` unset and a directory holding a team
    of this run's size (its agent files exactly ``agent_0`` .. ``agent_{K-1}``), each target agent
    starts from the source agent of its own index; else as it is (unset: agent 0 for every target).

    :param transfer: the run's transfer config.
    :param source: the source's path (a file, a run directory, an exported folder).
    :param targets: the run's target agents.
    :param num_agents: the run's team size, K.
    """
    if transfer.source_agent is not None or source.is_file():
        return transfer
    team = {file.name for file in find_checkpoints(source)}
    if team != {agent_file_name(i) for i in range(num_agents)}:
        return transfer  # another team size: every target from agent 0
    return dataclasses.replace(transfer, source_agent=list(targets))


def given_sources(plan: RunPlan, launch_dir: Path) -> list[list[Path]]:
    """``transfer.source`` resolved for each replica of ``plan``: the same checkpoints for every replica,
    except that a run of replicas as the source gives each replica of a run of replicas the source
    replica of its own name (``seed_<s>``), so a batch of seeds transfers seed for seed; a replica the
    source lacks is refused in one line. A source team of the run's size gives agent i to agent i
    unless ``transfer.source_agent`` says otherwise (:func:`team_to_team`).

    :param plan: the run (its ``transfer.source`` set).
    :param launch_dir: relative sources are taken from here.
    """
    transfer, num_targets = plan.config.transfer, len(plan.targets)
    path = source_path(transfer, launch_dir)
    by_name = {directory.name: directory for directory in RunDir(path).replica_dirs()}
    if not by_name or len(plan.replicas) == 1:
        team = team_to_team(transfer, path, plan.targets, plan.num_agents)
        return [resolve_source(team, launch_dir, num_targets)] * len(plan.replicas)
    missing = [replica.name for replica in plan.replicas if replica.name not in by_name]
    if missing:
        raise CheckpointError(
            f"transfer.source={transfer.source} is a run of replicas {', '.join(by_name)}, which has no "
            f"{', '.join(missing)}: each replica of this run starts from the source replica of its own name"
        )
    return [
        resolve_source(
            team_to_team(
                dataclasses.replace(transfer, source=str(by_name[replica.name])),
                by_name[replica.name],
                plan.targets,
                plan.num_agents,
            ),
            launch_dir,
            num_targets,
        )
        for replica in plan.replicas
    ]


def transfer_sources(plan: RunPlan, launch_dir: Path) -> list[list[Path]] | None:
    """The checkpoint of each target agent of each replica (one list for a lone run): None without
    transfer (or when resuming, which has its agents already), ``transfer.source`` resolved against
    ``launch_dir`` for every replica (:func:`given_sources`), else a source pretrained with each
    replica's own seed on its own map (or on the map ``transfer.source_map_shift`` map seeds further):
    the one single-agent source for every target, one per target from that agent's own start
    (``per_agent``), or the team source's member ``transfer.source_agent`` (one per target)."""
    config = plan.config
    if not config.transfer.enabled or config.resume:
        return None
    num_targets = len(plan.targets)
    if config.transfer.source is not None:
        return given_sources(plan, launch_dir)
    task = SourceTask(config.transfer.source_task)
    if task is SourceTask.team:
        members = team_members(config.transfer, plan.num_agents, num_targets)
    elif config.transfer.source_agent is not None and not isinstance(config.transfer.source_agent, int):
        raise TransferError(
            f"transfer.source_agent={list(config.transfer.source_agent)} picks agents of "
            "transfer.source or of a team source; the pretrained source is one agent (set "
            "transfer.source, or transfer.source_task=team)"
        )
    else:
        members = [0] * num_targets
    if task is not SourceTask.per_agent:
        [pretraining] = plan.chain
        entries = pretrained_sources(plan, pretraining, launch_dir)
        return [[entry.agent_checkpoint(i) for i in members] for entry in entries]
    per_target = []  # the chain holds one pretraining per target, from that agent's start
    for agent, pretraining in zip(plan.targets, plan.chain):
        log.info("transfer: the source of agent %d learns TreasureHunt-v0 from agent %d's start", agent, agent)
        per_target.append(pretrained_sources(plan, pretraining, launch_dir))
    return [[entries[r].agent_checkpoint(0) for entries in per_target] for r in range(len(plan.replicas))]
