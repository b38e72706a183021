"""The run plan: a composed config checked once and turned into everything a run is made of.

:func:`plan_run` is the one place a config is validated, its replicas derived, their maps resolved and
the transfer targets checked; the command line calls it once, and the sources
(:mod:`dqn_transfer.sources`) and the trainer receive the :class:`RunPlan` and never do so again. A plan
also holds the runs its transfer source comes from (its *chain*): the pretraining of the source
(``transfer.source`` unset), or the curriculum's stages, easiest first, each a plan of its own.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from dqn_transfer.agents import check_device
from dqn_transfer.config import (
    CONFIG_DIR,
    ConfigError,
    CurriculumConfig,
    TrainConfig,
    TransferConfig,
    replica_configs,
    validate,
)
from dqn_transfer.enums import SourceTask
from dqn_transfer.envs import Game, GridMap, PettingZooGame, UnsupportedEnv, make_game
from dqn_transfer.envs.game import game_on
from dqn_transfer.envs.settings import DEFAULTS, ENV_KEYS, MAP_KEYS, EnvConfig
from dqn_transfer.exchange import check_exchange
from dqn_transfer.training.resources import MAX_SIZE, Estimate, check_memory, check_size, estimate
from dqn_transfer.transfer.warm_start import transfer_targets


@dataclass(frozen=True)
class ReplicaPlan:
    """One replica of a run: its lone-run config (own seed and map seed), its resolved map (None for a game
    named by ``env.factory``), and the name of its directory inside a batch's run directory."""

    config: TrainConfig
    grid_map: GridMap | None
    name: str
    source_task: bool = False  # plays the single-agent source task of its map

    def new_game(self) -> Game:
        """A fresh game on the replica's map (the map is never resolved again), or from ``env.factory``."""
        if self.grid_map is None:
            return other_game(self.config.env)
        game = game_on(self.grid_map, self.config.env)
        return game.single_agent_game() if self.source_task else game

    def with_start_of(self, agent: int) -> ReplicaPlan:
        """The replica on its map with agent ``agent``'s start as agent 0's (:meth:`GridMap.with_start_of`):
        its single-agent source task starts from that agent's cell."""
        assert self.grid_map is not None  # a source task is the treasure hunt's (_plan_other_game refuses it)
        return dataclasses.replace(self, grid_map=self.grid_map.with_start_of(agent))

    @property
    def identity(self) -> str:
        """What names the replica's game in cache keys: its map's layout, or the other game's factory,
        kwargs and spaces."""
        return self.new_game().identity() if self.grid_map is None else self.grid_map.layout


@dataclass(frozen=True)
class RunPlan:
    """A validated run: its config, its replicas (one for a lone run), its team size, the agents a
    transfer warm-starts (none without transfer), whether it trains the single-agent source task, and
    the runs before it whose agents it starts from (:func:`plan_run`)."""

    config: TrainConfig
    replicas: tuple[ReplicaPlan, ...]
    num_agents: int
    targets: tuple[int, ...]
    source_task: bool = False
    chain: tuple[RunPlan, ...] = ()
    # A share of a batch (share()): the batch's replicas in all, and this share's first one among them.
    batch_size: int = 0  # 0: the plan is the whole run
    first_replica: int = 0

    @property
    def is_lone_run(self) -> bool:
        """One replica, trained in the run directory itself (a batch's replicas get directories of their own)."""
        return (self.batch_size or len(self.replicas)) == 1

    def replica_dirs(self, run_dir: Path) -> list[Path]:
        """Where each replica of the plan is trained: the run directory itself for a lone run, else the
        replica's own directory in it."""
        return [run_dir] if self.is_lone_run else [run_dir / replica.name for replica in self.replicas]

    def share(self, first: int, count: int) -> RunPlan:
        """Replicas ``first .. first + count - 1`` of the run, trained into the same run directory by a
        worker process of their own (:mod:`~dqn_transfer.training.workers`)."""
        return dataclasses.replace(
            self,
            replicas=self.replicas[first : first + count],
            batch_size=self.batch_size or len(self.replicas),
            first_replica=self.first_replica + first,
        )

    def lone(self, index: int) -> RunPlan:
        """Replica ``index`` as a run of its own (its config is a lone run's)."""
        replica = dataclasses.replace(self.replicas[index], name="")
        return dataclasses.replace(self, config=replica.config, replicas=(replica,), chain=())

    def with_start_of(self, agent: int) -> RunPlan:
        """The same run with each replica's agent 0 starting from agent ``agent``'s start."""
        return dataclasses.replace(self, replicas=tuple(replica.with_start_of(agent) for replica in self.replicas))

    def resuming(self, resume: bool) -> RunPlan:
        """The same run, continued from its checkpoint (``resume``) or started afresh."""
        return dataclasses.replace(
            self,
            config=dataclasses.replace(self.config, resume=resume),
            replicas=tuple(
                dataclasses.replace(r, config=dataclasses.replace(r.config, resume=resume)) for r in self.replicas
            ),
        )


def plan_run(config: TrainConfig, *, source_task: bool = False) -> RunPlan:
    """Validate ``config`` and plan it, with the runs its transfer source comes from: none when
    resuming (the run has its agents already), without transfer or with ``transfer.source`` given; the
    curriculum's stages; else the source's pretraining (``transfer.source_task=per_agent``: one per
    target agent, in ``targets`` order, each from that agent's start). ``source_task``: the run trains
    the single-agent source task of its map."""
    plan = _plan(config, source_task)
    if source_task or config.resume or not config.transfer.enabled:
        return plan
    if config.curriculum.stages:
        chain = tuple(_stage_plan(config, n) for n in range(len(config.curriculum.stages)))
    elif config.transfer.source is None:
        task = SourceTask(config.transfer.source_task)
        pretraining = _plan(source_config(config), source_task=task is not SourceTask.team)
        per_agent = task is SourceTask.per_agent
        chain = tuple(pretraining.with_start_of(i) for i in plan.targets) if per_agent else (pretraining,)
    else:
        chain = ()
    return dataclasses.replace(plan, chain=chain)


def _plan(config: TrainConfig, source_task: bool) -> RunPlan:
    validate(config)
    check_device(config.device)
    check_exchange(config)
    if config.env.factory is not None:
        return _plan_other_game(config, source_task)
    check_map_size(config.env)
    # The first replica's map (cheap, once its side is bounded) tells the run's size; the memory it
    # will need is checked before any other map, learner or buffer is made.
    first = _resolve_map(config.env)
    check_size(first.size, "env.layout_file's side" if config.env.layout_file is not None else "env.size")
    first_game = game_on(first, config.env)
    if source_task:
        first_game = first_game.single_agent_game()
    check_memory(config, first.size, first_game.num_agents, first.num_treasures)
    replicas = []
    for replica in replica_configs(config):
        same_map = replica.env == config.env
        grid_map = first if same_map else _resolve_map(replica.env)
        replicas.append(ReplicaPlan(replica, grid_map, replica_name(replica, config), source_task))
    num_agents = replicas[0].new_game().num_agents
    transferred = config.transfer.enabled and not source_task
    targets = tuple(transfer_targets(config, num_agents)) if transferred else ()
    return RunPlan(config, tuple(replicas), num_agents, targets, source_task)


def memory_estimate(config: TrainConfig) -> Estimate | None:
    """The memory a run of ``config`` will hold at its peak (:func:`~.resources.estimate`, on its first
    replica's map, as :func:`plan_run` checks it); None for a game ``env.factory`` names, not estimated."""
    if config.env.factory is not None:
        return None
    check_map_size(config.env)
    first = _resolve_map(config.env)
    return estimate(config, first.size, game_on(first, config.env).num_agents, first.num_treasures)


def _plan_other_game(config: TrainConfig, source_task: bool) -> RunPlan:
    """The plan of a run on the PettingZoo env ``env.factory`` names, built once here to refuse an env the
    adapter cannot play (:class:`~dqn_transfer.envs.UnsupportedEnv`) in one line."""
    factory = config.env.factory
    if source_task:
        raise ConfigError(
            f"env.factory={factory}: transfer.source_task=single and per_agent pretrain on the treasure hunt's "
            "single-agent task; give transfer.source=PATH or pretrain on this game with transfer.source_task=team"
        )
    if config.curriculum.stages:
        raise ConfigError(
            f"curriculum: its stages change the treasure hunt's env; env.factory={factory} is another game"
        )
    if foreign := treasure_hunt_settings(config.env):
        settings = ", ".join(f"env.{key}={plain(getattr(config.env, key))}" for key in foreign)
        raise ConfigError(
            f"{settings}: the treasure hunt's, but env.factory={factory} is another game, which does not read "
            f"{'it' if len(foreign) == 1 else 'them'} (leave {'it' if len(foreign) == 1 else 'them'} unset)"
        )
    if config.replicas.maps > 1 and not config.env.fixed_start:
        raise ConfigError(
            f"replicas.maps={config.replicas.maps} varies the map seed, which env.factory={factory} reads only as "
            "a fixed instance's reset seed: add env.fixed_start=true, or use replicas.seeds"
        )
    try:
        num_agents = other_game(config.env).num_agents
    except UnsupportedEnv as err:
        raise ConfigError(str(err)) from None
    replicas = tuple(ReplicaPlan(replica, None, replica_name(replica, config)) for replica in replica_configs(config))
    targets = tuple(transfer_targets(config, num_agents)) if config.transfer.enabled else ()
    return RunPlan(config, replicas, num_agents, targets)


def other_game(env: EnvConfig) -> PettingZooGame:
    """The game ``env.factory`` makes; with ``env.fixed_start``, the instance of reset seed ``env.map_seed``."""
    return PettingZooGame(str(env.factory), env.kwargs, env.map_seed if env.fixed_start else None)


# The keys that generate a map, which a layout makes pointless.
GENERATION_KEYS = tuple(key for key in MAP_KEYS if key not in ("layout", "layout_file"))
# The treasure hunt's keys another game (env.factory) does not read: all but env.map_seed, its reset
# seed with env.fixed_start (and its instances' with replicas.maps).
UNREAD_BY_OTHER_GAMES = tuple(key for key in ENV_KEYS if key != "map_seed")


def plain(value: Any) -> Any:
    """A setting as the config files and the command line spell it (an enum by its value)."""
    return value.value if isinstance(value, Enum) else value


@functools.cache
def env_option_values() -> tuple[dict[str, Any], ...]:
    """The treasure hunt's keys as each ``env`` option (``conf/env/**.yaml``) gives them to a run,
    and the schema's defaults: the values a run has when its user set none of these keys."""
    options = [{key: plain(getattr(DEFAULTS, key)) for key in ENV_KEYS}]
    for path in sorted((CONFIG_DIR / "env").rglob("*.yaml")):
        values = yaml.safe_load(path.read_text()) or {}
        options.append({**options[0], **{key: values[key] for key in ENV_KEYS if key in values}})
    return tuple(options)


def set_by_user(env: EnvConfig, keys: tuple[str, ...]) -> list[str]:
    """The ``keys`` of ``env`` its user set: those whose values differ from the env option nearest to ``env``
    over ``keys`` (or from the schema's defaults). Which option composed the run is not in the config; the
    nearest stands for it, so that a group's own values (env=simple's ``map_seed`` 6) are never the user's."""
    settings = {key: plain(value) for key, value in dataclasses.asdict(env).items()}
    differing = lambda option: [key for key in keys if settings[key] != option[key]]  # noqa: E731
    return min((differing(option) for option in env_option_values()), key=len)


def treasure_hunt_settings(env: EnvConfig) -> list[str]:
    """The treasure hunt's keys (``env.size``, ``mode``, chests, traps, ...) set on a run of another game
    (``env.factory``), which would ignore them."""
    return set_by_user(env, UNREAD_BY_OTHER_GAMES)


def given_env(env: EnvConfig) -> dict[str, Any]:
    """``env`` as ``make_game`` keys, with a layout's generation keys that the user did not set left out
    (None: not given), so that the "a layout fixes the map" warning names only the user's own. "Not set"
    is "as the env option nearest to ``env`` (or the schema default) has it": ``env=simple
    env.layout_file=map.txt`` warns about nothing, although env=simple's ``map_seed`` is 6. Without a
    layout, every key."""
    settings = dataclasses.asdict(env)
    if env.layout is None and env.layout_file is None:
        return settings
    given = set_by_user(env, GENERATION_KEYS)
    return {**settings, **{key: None for key in GENERATION_KEYS if key not in given}}


def _resolve_map(env: EnvConfig) -> GridMap:
    try:
        return make_game(**given_env(env)).map
    except (ValueError, OSError) as err:
        raise ConfigError(f"env: {err}") from err


def check_map_size(env: EnvConfig) -> None:
    """Bound the map's side before the map is generated or read (:func:`~.resources.check_size`)."""
    if env.layout is not None:
        check_size(len(str(env.layout).strip().splitlines()), "env.layout's side")
    elif env.layout_file is not None:
        path = Path(env.layout_file).expanduser()
        if path.exists() and not path.is_file():
            raise ConfigError(f"env.layout_file={env.layout_file} is not a regular file")
        limit = (MAX_SIZE + 1) * (MAX_SIZE + 2) * 4  # MAX_SIZE rows of MAX_SIZE cells, generous line ends
        if path.is_file() and path.stat().st_size > limit:
            raise ConfigError(
                f"env.layout_file={env.layout_file} holds {path.stat().st_size} bytes: too large for a map "
                f"of at most {MAX_SIZE}x{MAX_SIZE} cells"
            )
    else:
        check_size(env.size)


def replica_name(replica: TrainConfig, config: TrainConfig) -> str:
    """``seed_<s>``, and ``-map_<m>`` when the batch varies the map too."""
    return f"seed_{replica.seed}" + (f"-map_{replica.env.map_seed}" if config.replicas.maps > 1 else "")


# ------------------------------------------------------------------------------ the runs before a run


def source_map(config: TrainConfig) -> TrainConfig:
    """``config`` on the map its source is pretrained on: ``env.map_seed`` moved by
    ``transfer.source_map_shift`` (``config`` itself for no shift). For a batch of replicas, each
    replica's map seed moves by the shift."""
    shift = config.transfer.source_map_shift
    if shift == 0:
        return config
    return dataclasses.replace(config, env=dataclasses.replace(config.env, map_seed=config.env.map_seed + shift))


def source_config(config: TrainConfig) -> TrainConfig:
    """The config of the source pretraining run: the same learner and seed, on the source's map
    (:func:`source_map`), with no transfer. ``transfer.source_task`` says which game of it is played
    (the plan's ``source_task``): TreasureHunt-v0, or the run's own team game."""
    pretrain_steps = config.transfer.pretrain_steps
    return dataclasses.replace(
        source_map(config),
        transfer=TransferConfig(),
        total_steps=pretrain_steps,
        eval_every=max(1, pretrain_steps // 10),
        checkpoint_every=max(1, pretrain_steps // 4),
        resume=False,
    )


def stage_config(config: TrainConfig, n: int) -> TrainConfig:
    """Curriculum stage ``n``'s config: ``config`` with the stage's env and steps, warm-started from stage
    ``n - 1``. Works for a lone run and for a batch of replicas."""
    stage = config.curriculum.stages[n]
    try:
        env = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(config.env), dict(stage.env)))
    except OmegaConfBaseException as err:
        raise ConfigError(f"curriculum.stages[{n}].env: {str(err).splitlines()[0]}") from None
    transfer = (
        TransferConfig()
        if n == 0
        else dataclasses.replace(
            config.transfer,
            enabled=True,
            source=None,
            targets=None,
            source_agent=stage.source_agent,
            offset=list(stage.offset),
        )
    )
    return dataclasses.replace(
        config,
        env=env,  # type: ignore[arg-type]
        total_steps=stage.steps,
        transfer=transfer,
        curriculum=CurriculumConfig(),
        resume=False,
    )


def _stage_plan(config: TrainConfig, n: int) -> RunPlan:
    staged = stage_config(config, n)
    try:
        return _plan(staged, source_task=False)
    except ConfigError as err:
        raise ConfigError(
            f"curriculum.stages[{n}] ({describe_stage(config.curriculum.stages[n].env)}): {err}"
        ) from None


def describe_stage(env: dict) -> str:
    """A stage's env changes in one short phrase (a layout by its side alone: it fixes the map's counts)."""
    if env.get("layout"):
        side = len(str(env["layout"]).splitlines())
        return f"{side}x{side} layout"
    return ", ".join(f"{key}={value}" for key, value in env.items()) or "the run's env"
