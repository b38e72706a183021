"""Typed configuration schemas, registered in Hydra's ConfigStore.

The YAML files under ``conf/`` are merged *into* these dataclasses, so a misspelt key
(``agent.learning_rate``) or a wrong type (``agent.gamma=high``) is refused by Hydra before
anything runs.  Enums give the closed vocabularies (modes, algorithms) the same protection.
Range checks that a type cannot express live in :func:`validate`. The ``env`` schema is the game's
own :class:`~dqn_transfer.envs.settings.EnvConfig`; the learners are built from :class:`AgentConfig`:
each default is written once, here or there, with the one-line description ``--help`` shows
(:func:`~dqn_transfer.documented.documented`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import Enum
from importlib.resources import files
from pathlib import Path
from typing import Any, Dict, List, Optional

import yaml
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, ListConfig, OmegaConf

from dqn_transfer.documented import documented
from dqn_transfer.enums import (
    Algorithm,
    Contention,
    Device,
    Engine,
    Exchange,
    Extra,
    Fill,
    Logger,
    Mixer,
    Objective,
    SourceTask,
    numpy_implements,
    values,
)
from dqn_transfer.envs.settings import ENV_KEYS, FACTORY_PLACEHOLDER, EnvConfig

# The config groups: conf/ at the repository's root, the package dqn_transfer.conf once installed (pyproject.toml
# maps it), so the import system finds it from any directory, in a wheel's install as in an editable one.
try:
    CONFIG_DIR = Path(str(files("dqn_transfer.conf")))
except ModuleNotFoundError:  # a checkout used without installing the package: its conf/ beside dqn_transfer/
    CONFIG_DIR = Path(__file__).resolve().parents[2] / "conf"


@dataclass
class AgentConfig:
    """Learner hyperparameters, with Stable-Baselines3's names (and meaning) where one exists.

    The DQN learners read all but the ``eps_*`` / ``exploration_fraction`` keys (the trainer's
    exploration schedule); the tabular ones read ``algorithm``, ``lr`` and ``gamma``.
    """

    algorithm: Algorithm = documented(
        Algorithm.double_dqn, "sarsa | qlearning (tabular) or dqn | double_dqn (networks)"
    )
    lr: float = documented(1e-3, "Adam step size (DQN) or alpha (tabular)")
    gamma: float = documented(0.99, "discount")
    batch_size: int = documented(64, "transitions per agent per gradient step")
    buffer_size: int = documented(50_000, "replay capacity per agent")
    learning_starts: int = documented(1_000, "env steps of pure collection before the first update")
    train_freq: int = documented(1, "env steps between updates")
    gradient_steps: int = documented(1, "gradient steps per update")
    target_update: int = documented(1, "env steps between target-network updates (SB3's target_update_interval)")
    tau: float = documented(0.01, "each target update: target <- tau*online + (1-tau)*target; 1.0 = hard copy")
    hidden: List[int] = documented(factory=lambda: [64, 64], doc="MLP hidden sizes")
    eps_start: float = documented(1.0, "initial exploration rate")
    eps_end: float = documented(0.05, "final exploration rate")
    exploration_fraction: float = documented(0.5, "fraction of total_steps over which epsilon decays linearly")
    max_grad_norm: float = documented(10.0, "gradient-norm clip, per agent")
    share_parameters: bool = documented(False, "one network for all agents (parameter-sharing baseline)")
    engine: Engine = documented(
        Engine.auto,
        "DQN arithmetic: auto (numpy on device=cpu, else torch) | torch (any device, any loss: the update in "
        "autograd) | numpy (CPU, no torch import, DQN / Double DQN / VDN only: the fastest on these small networks)",
    )
    agent_id_input: bool = documented(
        False,
        "with share_parameters: append a one-hot of the agent's index to its observation (segment agent_id), "
        "so the shared network can tell the agents apart",
    )
    mixer: Mixer = documented(
        Mixer.none,
        "none (each agent on its own TD error) | vdn (value decomposition, Sunehag et al. 2018: the team trained "
        "jointly, Q_tot = sum of the live agents' Q-values on the sum of their rewards; cooperative games)",
    )


# Each AgentConfig key -> Stable-Baselines3 DQN's keyword for the same quantity ("hidden" becomes
# policy_kwargs.net_arch).
SB3_NAMES = {
    "lr": "learning_rate",
    "gamma": "gamma",
    "batch_size": "batch_size",
    "buffer_size": "buffer_size",
    "learning_starts": "learning_starts",
    "train_freq": "train_freq",
    "gradient_steps": "gradient_steps",
    "target_update": "target_update_interval",
    "tau": "tau",
    "max_grad_norm": "max_grad_norm",
    "eps_start": "exploration_initial_eps",
    "eps_end": "exploration_final_eps",
    "exploration_fraction": "exploration_fraction",
}


@dataclass
class TransferConfig:
    """Warm start from a pretrained agent, and knowledge exchange inside the team (docs/transfer.md)."""

    enabled: bool = documented(False, "start the target agents from a source agent (the group transfer=on)")
    source: Optional[str] = documented(
        None,
        "checkpoint file, run directory or exported folder (a run of replicas: each replica from its seed's); "
        "null: pretrain one (transfer.source_task)",
    )
    source_agent: Any = documented(
        None,
        "which agent_{i}.safetensors of a directory (or member of a team source): one "
        "index for every target, or a list with one per target (another team size); null: agent i from "
        "agent i of a directory holding a team of this run's size, else agent 0",
    )
    pretrain_steps: int = documented(20_000, "env steps of source-task pretraining when no source is given")
    source_task: SourceTask = documented(
        SourceTask.single,
        "what a pretrained source learns: single (TreasureHunt-v0, "
        "agent 0 alone) | per_agent (TreasureHunt-v0 from each target agent's own start: target i "
        "starts from a lone agent pretrained from agent i's start) | team (this run's own game; targets "
        "start from member source_agent)",
    )
    chest_aware: bool = documented(
        False,
        "tabular learners, a source pretrained on TreasureHunt-v0 (source_task single | per_agent): use the "
        "source's values only while the chest nearest its start is full in the target's `treasures` "
        "observation; once it reads taken, a state starts at 0 like an empty table's",
    )
    source_map_shift: int = documented(0, "pretrain on the generated map of env.map_seed + this; 0: this run's map")
    cache_dir: Optional[str] = documented(None, "pretrained-source cache; null: <launch dir>/outputs/pretrained")
    targets: Optional[List[int]] = documented(None, "agents that receive the transfer; null: all")
    offset: List[int] = documented(
        factory=lambda: [0, 0], doc="[row, col] of the source map's top-left cell in this run's (larger) map"
    )
    fill: Fill = documented(
        Fill.zero,
        "this run's cells outside the source map: zero (no input weights) | nearest (the nearest source cell's)",
    )
    reset_optimizer: bool = documented(True, "start Adam moments afresh (the source's belong to another task)")
    epsilon_start: float = documented(0.3, "transferred agents explore less than agent.eps_start")
    freeze: List[int] = documented(factory=list, doc="indices of layers kept fixed")
    exchange: Exchange = documented(
        Exchange.none,
        "knowledge exchange inside the team during training: none | best | shared_replay | experience (DQN) | "
        "confidence | advice (tabular learners) | sham (control: shared_replay's volume, each agent's own moves)",
    )
    exchange_every: int = documented(20, "episodes between exchanges")
    exchange_tau: float = documented(0.5, "'best': weight of the best agent in the soft copy")
    confidence_weight: float = documented(
        1.0,
        "'confidence': in (0, 1], scales the merge weight n_j / (n_i + n_j) toward the team-mate j that "
        "visited a state most (only where it visited it more than agent i)",
    )
    advice_ask_below: int = documented(3, "'advice': an agent asks when it has visited its state fewer times than this")
    advice_answer_from: int = documented(
        10, "'advice': the team-mate that visited the state most answers if it visited it at least this often"
    )
    advice_budget: int = documented(500, "'advice': advised steps per agent per run")
    experience_lambda: float = documented(
        1.0,
        "'experience': weight of the team-mates' samples in each agent's loss, relative to its own (0: no "
        "sharing in the loss)",
    )


@dataclass
class ReplicasConfig:
    """Independent runs batched in one command (docs/sweeps.md): ``seeds`` x ``maps`` replicas, seeds
    ``seed .. seed + seeds - 1`` crossed with map seeds ``env.map_seed .. env.map_seed + maps - 1``."""

    seeds: int = documented(1, "replicas with consecutive seeds")
    maps: int = documented(1, "replicas with consecutive map seeds (a generated map only)")
    workers: str = documented(
        "auto", "processes the replicas are split across: auto (the cores, shared with a sweep's jobs at once) or N"
    )


@dataclass
class StageConfig:
    """One curriculum stage before the run: the run's env changed by ``env``, trained for ``steps``."""

    env: Dict[str, Any] = documented(factory=dict, doc="env keys this stage changes, e.g. {size: 5, num_treasures: 1}")
    steps: int = documented(10_000, "env steps of this stage")
    offset: List[int] = documented(
        factory=lambda: [0, 0], doc="where the previous stage's map sits in this one (transfer.offset)"
    )
    source_agent: Any = documented(
        0, "the previous stage's agent(s) this stage's agents start from (transfer.source_agent)"
    )


@dataclass
class CurriculumConfig:
    """Stages trained before the run, each warm-starting the next; the run is the last stage and
    warm-starts from the one before (docs/curriculum.md)."""

    stages: List[StageConfig] = documented(
        factory=list, doc="the stages before this run, easiest first; empty: no curriculum"
    )
    cache_dir: Optional[str] = documented(None, "finished stages are kept here; null: <launch dir>/outputs/curriculum")


@dataclass
class TrainConfig:
    env: EnvConfig = field(default_factory=EnvConfig)
    agent: AgentConfig = field(default_factory=AgentConfig)
    transfer: TransferConfig = field(default_factory=TransferConfig)
    replicas: ReplicasConfig = field(default_factory=ReplicasConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    seed: int = documented(0, "seeds the learners, exploration and episode resets")
    total_steps: int = documented(20_000, "joint env steps (every live agent acts once)")
    eval_every: int = documented(1_000, "env steps between greedy evaluations")
    eval_episodes: int = documented(10, "greedy episodes per evaluation")
    checkpoint_every: int = documented(5_000, "env steps between checkpoints")
    progress: bool = documented(True, "tqdm progress bar, on a terminal only (never in a captured stream)")
    resume: bool = documented(False, "continue the run in hydra.run.dir from its last checkpoint")
    device: Device = documented(Device.cpu, "cpu | cuda | auto")
    threads: int = documented(
        1,
        "torch CPU threads (agent.engine=torch): tiny networks run fastest on one, and sweep jobs don't oversubscribe",
    )
    eval_pictures: Optional[bool] = documented(
        None,
        "TensorBoard's picture of each evaluation's first episode and the agents' Q-value histograms there "
        "(the metrics are the same without); null: the first replica's (a lone run's), not in a multirun sweep (-m); "
        "true: every replica's",
    )
    objective: Objective = documented(
        Objective.final,
        "final | mean: the team return a sweeper (Optuna) optimises, the last evaluation's or the mean of all "
        "evaluations; over a run's replicas, their mean",
    )
    logger: List[Logger] = documented(
        factory=lambda: [Logger.tensorboard],
        doc="where the scalars, evaluation pictures and config go, one or more of tensorboard | csv "
        "(scalars.csv) | wandb (Weights & Biases, the wandb extra; replicas as runs of one group)",
    )


def register_configs() -> None:
    """Make the schemas available to ``conf/config.yaml`` (its defaults list names them)."""
    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)


class ConfigError(ValueError):
    """A configuration value that is well-typed but out of range."""


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


# Range rules per key (a dotted path into the config): the bounds a type cannot express.
_AT_LEAST = {
    "env.size": 2,
    "env.num_treasures": 1,
    "env.max_steps": 1,
    "env.view_radius": 0,
    "agent.batch_size": 1,
    "agent.buffer_size": 1,
    "agent.learning_starts": 0,
    "agent.train_freq": 1,
    "agent.gradient_steps": 1,
    "agent.target_update": 1,
    "total_steps": 0,
    "eval_every": 1,
    "eval_episodes": 1,
    "checkpoint_every": 1,
    "threads": 1,
    "transfer.pretrain_steps": 1,
    "transfer.exchange_every": 1,
    "transfer.advice_ask_below": 0,
    "transfer.advice_answer_from": 1,
    "transfer.advice_budget": 0,
    "replicas.seeds": 1,
    "replicas.maps": 1,
}
_POSITIVE = ("agent.lr", "agent.max_grad_norm")
_REWARDS = ("env.treasure_reward", "env.trap_reward", "env.step_reward")
MAX_SEED = 2**63 - 1  # torch's generators take a signed 64-bit seed
_IN_UNIT_INTERVAL = (
    "agent.gamma",
    "agent.eps_start",
    "agent.eps_end",
    "agent.exploration_fraction",
    "transfer.epsilon_start",
)  # [0, 1]
_IN_HALF_OPEN_UNIT = ("agent.tau", "transfer.exchange_tau", "transfer.confidence_weight")  # (0, 1]


def _value(cfg: DictConfig | TrainConfig, key: str) -> Any:
    value = cfg
    for part in key.split("."):
        value = getattr(value, part)
    return value


def validate(cfg: DictConfig | TrainConfig) -> None:
    """Range checks that types cannot express; raises ConfigError naming the key."""
    env, agent, transfer = cfg.env, cfg.agent, cfg.transfer
    for key, low in _AT_LEAST.items():
        value = _value(cfg, key)
        _check(value is None or value >= low, f"{key} must be >= {low}, got {value}")  # None: not set (max_steps)
    for key in _POSITIVE:
        _check(0 < _value(cfg, key) < math.inf, f"{key} must be > 0 and finite, got {_value(cfg, key)}")
    for key in _REWARDS:
        _check(math.isfinite(_value(cfg, key)), f"{key} must be a finite number, got {_value(cfg, key)}")
    for key, count in (("seed", cfg.replicas.seeds), ("env.map_seed", cfg.replicas.maps)):
        value = _value(cfg, key)
        _check(
            value >= 0 and value + count <= MAX_SEED,
            f"{key} must be in [0, 2^63 - 1] (with its replicas), got {value}",
        )
    for key in _IN_UNIT_INTERVAL:
        _check(0.0 <= _value(cfg, key) <= 1.0, f"{key} must be in [0, 1], got {_value(cfg, key)}")
    for key in _IN_HALF_OPEN_UNIT:
        _check(0.0 < _value(cfg, key) <= 1.0, f"{key} must be in (0, 1], got {_value(cfg, key)}")
    workers = str(cfg.replicas.workers)
    _check(
        workers == "auto" or (workers.isdigit() and int(workers) >= 1),
        f"replicas.workers must be auto or a number of processes >= 1, got {workers}",
    )
    _check(0.0 <= env.complexity < 1.0, f"env.complexity must be in [0, 1), got {env.complexity}")
    _check(
        len(agent.hidden) >= 1 and all(h >= 1 for h in agent.hidden),
        f"agent.hidden must be a non-empty list of positive sizes, got {list(agent.hidden)}",
    )
    _check(
        transfer.enabled or not transfer.freeze,
        f"transfer.freeze={list(transfer.freeze)} keeps transferred layers fixed: it needs transfer=on",
    )
    is_tabular = Algorithm(agent.algorithm).is_tabular
    if is_tabular:
        _check(not transfer.freeze, "transfer.freeze applies to network layers; tabular learners have none")
        _check(
            transfer.reset_optimizer,
            "transfer.reset_optimizer=false carries a source's Adam moments over; tabular learners have none",
        )
    else:
        # Every batch is drawn from the replay: one smaller than a batch repeats its few transitions in each
        # (SB3 and CleanRL presume buffer_size >= batch_size).
        _check(
            agent.buffer_size >= agent.batch_size,
            f"agent.buffer_size={agent.buffer_size} is smaller than agent.batch_size={agent.batch_size}: a "
            "replay must hold at least one batch (raise agent.buffer_size or lower agent.batch_size)",
        )
        layers = len(agent.hidden) + 1
        _check(
            all(-layers <= i < layers for i in transfer.freeze),
            f"transfer.freeze={list(transfer.freeze)}: the network has {layers} layers (0..{layers - 1})",
        )
    _check(
        Engine(agent.engine) is not Engine.numpy or Device(cfg.device) is not Device.cuda,
        "agent.engine=numpy runs on the CPU: use device=cpu (or agent.engine=torch for device=cuda)",
    )
    _check(
        Engine(agent.engine) is not Engine.numpy or is_tabular or numpy_implements(agent.algorithm, agent.mixer),
        f"agent.engine=numpy implements DQN, Double DQN and VDN only, not agent.algorithm="
        f"{Algorithm(agent.algorithm).value} with agent.mixer={Mixer(agent.mixer).value}: use agent.engine=torch",
    )
    _check(
        cfg.replicas.maps == 1 or (env.layout is None and env.layout_file is None),
        f"replicas.maps={cfg.replicas.maps} needs a generated map; a layout fixes the map (use replicas.seeds)",
    )
    _check(
        Contention(env.contention) is Contention.any or (env.layout is None and env.layout_file is None),
        f"env.contention={Contention(env.contention).value} chooses among generated maps; a layout fixes the map "
        "(leave env.contention at any, or drop the layout)",
    )
    _check(
        env.factory != FACTORY_PLACEHOLDER,
        f"env=pettingzoo needs env.factory={FACTORY_PLACEHOLDER}, the function returning your PettingZoo ParallelEnv "
        "(e.g. env.factory=mpe2.simple_spread_v3:parallel_env)",
    )
    _check(
        env.factory is not None or not env.fixed_start,
        "env.fixed_start=true fixes the episodes of another game (env.factory); the treasure hunt's map is "
        "fixed by env.map_seed already",
    )
    _check_logger(cfg.logger)
    _check_offset("transfer.offset", transfer.offset)
    _check(
        transfer.enabled or (list(transfer.offset) == [0, 0] and Fill(transfer.fill) is Fill.zero),
        f"transfer.offset={list(transfer.offset)} / transfer.fill={Fill(transfer.fill).value} place a source's "
        "map in this run's: they need transfer=on",
    )
    _check(
        transfer.enabled or transfer.source is None,
        f"transfer.source={transfer.source} is the agent this run starts from: it needs transfer=on",
    )
    if transfer.source_agent is not None:  # null: chosen by the source (dqn_transfer.sources.resolve)
        _check_source_agent("transfer.source_agent", transfer.source_agent)
    _check_experience_lambda(cfg)
    _check_pretraining(cfg)
    _check_chest_aware(cfg)
    _check_curriculum(cfg)


def _check_experience_lambda(cfg: DictConfig | TrainConfig) -> None:
    """``transfer.experience_lambda`` weighs shared experience: it needs ``transfer.exchange=experience``.
    (What each exchange method needs is checked with the plan: :mod:`dqn_transfer.exchange`.)"""
    lam = cfg.transfer.experience_lambda
    _check(0.0 <= lam < math.inf, f"transfer.experience_lambda must be >= 0 and finite, got {lam}")
    _check(
        lam == 1.0 or Exchange(cfg.transfer.exchange) is Exchange.experience,
        f"transfer.experience_lambda={lam} weighs shared experience: it needs transfer.exchange=experience",
    )


def _check_pretraining(cfg: DictConfig | TrainConfig) -> None:
    """``transfer.source_task`` / ``transfer.source_map_shift`` say how a source is pretrained: they need
    transfer=on and no transfer.source (a given source is not pretrained); a shift needs a generated map."""
    env, transfer = cfg.env, cfg.transfer
    task, shift = SourceTask(transfer.source_task), transfer.source_map_shift
    given = [f"transfer.source_task={task.value}"] * (task is not SourceTask.single)
    given += [f"transfer.source_map_shift={shift}"] * (shift != 0)
    if not given:
        return
    what = " / ".join(given) + (" says" if len(given) == 1 else " say")
    _check(
        transfer.enabled,
        f"{what} how the transfer source is pretrained: {'it needs' if len(given) == 1 else 'they need'} transfer=on",
    )
    _check(
        transfer.source is None,
        f"{what} how the transfer source is pretrained, but transfer.source="
        f"{transfer.source} is not pretrained: leave one of them unset",
    )
    if shift != 0:
        _check(
            env.layout is None and env.layout_file is None,
            f"transfer.source_map_shift={shift} shifts env.map_seed, which needs a generated map; "
            "env.layout / env.layout_file fix the map",
        )
        _check(
            env.map_seed + shift >= 0,
            f"transfer.source_map_shift={shift}: the source's map seed "
            f"env.map_seed + shift = {env.map_seed + shift} must be >= 0",
        )


def _check_chest_aware(cfg: DictConfig | TrainConfig) -> None:
    """``transfer.chest_aware`` gates a table's start values from a lone source by the source's chest: it
    needs transfer=on, a tabular learner, a source pretrained on TreasureHunt-v0, the treasure hunt's
    chests and no curriculum."""
    transfer = cfg.transfer
    if not transfer.chest_aware:
        return
    what = "transfer.chest_aware=true uses a lone source's values only while its chest is full"
    algorithm, task = Algorithm(cfg.agent.algorithm), SourceTask(transfer.source_task)
    _check(transfer.enabled, f"{what}: it needs transfer=on")
    _check(
        algorithm.is_tabular,
        f"{what}, in a table's start values: it needs agent=sarsa or agent=qlearning, not agent={algorithm.value}",
    )
    _check(
        transfer.source is None and task is not SourceTask.team,
        f"{what}: it needs a source pretrained on TreasureHunt-v0 (transfer.source unset, transfer.source_task="
        f"single or per_agent), not transfer.source={transfer.source} with transfer.source_task={task.value}",
    )
    _check(cfg.env.factory is None, f"{what}: env.factory={cfg.env.factory} is another game, without chests")
    _check(not cfg.curriculum.stages, f"{what}: a curriculum's run starts from its last stage (leave it unset)")


def _check_logger(names: Any) -> None:
    """At least one logger; W&B's package installed if named (before the run writes anything)."""
    _check(
        len(names) >= 1, f"logger must name at least one of {', '.join(values(Logger))}, e.g. logger=[tensorboard,csv]"
    )
    if Logger.wandb in [Logger(name) for name in names]:
        try:
            import wandb  # noqa: F401
        except ImportError:
            raise ConfigError(
                f"logger=[...,wandb] needs the wandb package: {Extra.wandb.install} (or pip install wandb)"
            ) from None


def _check_curriculum(cfg: DictConfig | TrainConfig) -> None:
    stages = cfg.curriculum.stages
    if not stages:
        return
    _check(cfg.transfer.enabled, "curriculum: its last stage warm-starts this run, which needs transfer=on")
    _check(
        cfg.transfer.source is None,
        f"curriculum: this run starts from its last stage, not from "
        f"transfer.source={cfg.transfer.source} (leave it unset)",
    )
    _check(
        SourceTask(cfg.transfer.source_task) is SourceTask.single and cfg.transfer.source_map_shift == 0,
        "curriculum: this run starts from its last stage, not from a pretrained source (leave "
        "transfer.source_task and transfer.source_map_shift unset)",
    )
    for n, stage in enumerate(stages):
        unknown = sorted(set(stage.env) - set(ENV_KEYS))
        _check(not unknown, f"curriculum.stages[{n}].env: unknown env key(s) {unknown}")
        _check(stage.steps >= 1, f"curriculum.stages[{n}].steps must be >= 1, got {stage.steps}")
        _check_offset(f"curriculum.stages[{n}].offset", stage.offset)
        _check_source_agent(f"curriculum.stages[{n}].source_agent", stage.source_agent)


def _check_offset(key: str, offset: Any) -> None:
    _check(len(offset) == 2 and min(offset) >= 0, f"{key} must be [row, col] with both >= 0, got {list(offset)}")


def _is_index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _check_source_agent(key: str, value: Any) -> None:
    """One agent index, or a non-empty list of them (one per target agent)."""
    is_list = isinstance(value, (list, tuple, ListConfig)) and len(value) > 0 and all(_is_index(v) for v in value)
    _check(_is_index(value) or is_list, f"{key} must be an agent index or a non-empty list of them, got {value!r}")


def replica_configs(cfg: TrainConfig) -> list[TrainConfig]:
    """The lone-run config of every replica, map-major: ``(map_seed, seed)`` for map seeds
    ``env.map_seed ..`` and seeds ``seed ..`` (one config, itself with ``replicas`` 1 x 1, if no replicas)."""
    return [
        dataclasses.replace(
            cfg,
            seed=cfg.seed + s,
            replicas=ReplicasConfig(),
            env=dataclasses.replace(cfg.env, map_seed=cfg.env.map_seed + m),
        )
        for m in range(cfg.replicas.maps)
        for s in range(cfg.replicas.seeds)
    ]


def to_plain(cfg: DictConfig | TrainConfig | AgentConfig | TransferConfig | EnvConfig) -> dict[str, Any]:
    """A config (or one of its groups) as plain JSON-able data (enums as their names), for meta, logs
    and hashes: what ``OmegaConf.to_container(OmegaConf.structured(cfg), enum_to_str=True)`` gives,
    read straight from the dataclasses (30 ms less per config, which a batch of 100 replicas pays 200
    times; ``tests/test_config.py`` checks the two agree)."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)  # type: ignore[return-value]
    return _plain(cfg)


def plain_yaml(plain: dict[str, Any]) -> str:
    """:func:`to_plain`'s data as the YAML ``OmegaConf.to_yaml`` writes of it, by libyaml's dumper where
    PyYAML has it (2 ms against OmegaConf's 19 for a run's config, which a batch writes per replica;
    ``tests/test_config.py`` checks the two agree)."""
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return yaml.dump(plain, Dumper=dumper, default_flow_style=False, allow_unicode=True, sort_keys=False)


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Enum):
        return value.name
    if isinstance(value, (list, tuple, ListConfig)):
        return [_plain(item) for item in value]
    if isinstance(value, (dict, DictConfig)):
        return {key: _plain(item) for key, item in value.items()}
    return value
