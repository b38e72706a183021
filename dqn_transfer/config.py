"""Typed configuration schemas, registered in Hydra's ConfigStore.

The YAML files under ``conf/`` are merged *into* these dataclasses, so a misspelt key
(``agent.learning_rate``) or a wrong type (``agent.gamma=high``) is refused by Hydra before
anything runs.  Enums give the closed vocabularies (modes, algorithms) the same protection.
Range checks that a type cannot express live in :func:`validate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any, List, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf


class Mode(Enum):
    competitive = "competitive"
    cooperative = "cooperative"
    deliberative = "deliberative"


class RewardMode(Enum):
    individual = "individual"
    team = "team"


class ObsEncoding(Enum):
    onehot = "onehot"
    coords = "coords"


class Algorithm(Enum):
    sarsa = "sarsa"
    qlearning = "qlearning"
    dqn = "dqn"
    double_dqn = "double_dqn"


class Exchange(Enum):
    none = "none"
    best = "best"
    shared_replay = "shared_replay"


class Device(Enum):
    cpu = "cpu"
    cuda = "cuda"
    auto = "auto"


TABULAR = (Algorithm.sarsa, Algorithm.qlearning)


@dataclass
class EnvConfig:
    """The game (DESIGN §3). A ``layout``/``layout_file`` fixes size and counts."""

    size: int = 6  # grid side n
    num_treasures: int = 2  # chests k
    num_traps: Optional[int] = None  # default k
    num_agents: Optional[int] = None  # default k
    complexity: float = 0.1  # Rc: round(Rc*n*n) obstacles
    map_seed: int = 0  # the map is fixed for a run; episodes reset agents and chests only
    layout: Optional[str] = None  # ASCII map (rows of . # T X 0-9)
    layout_file: Optional[str] = None  # path to an ASCII map
    max_steps: Optional[int] = None  # truncation horizon, default n*n
    mode: Mode = Mode.competitive  # how s_env is kept: no communication / announcements / coordinator
    reward_mode: RewardMode = RewardMode.individual
    obs_encoding: ObsEncoding = ObsEncoding.onehot
    view_radius: int = 0  # 0: no egocentric view segment
    treasure_reward: float = 100.0
    trap_reward: float = -100.0
    step_reward: float = -1.0
    render_mode: Optional[str] = None  # accepted for the env kwargs of DESIGN §8; training does not render


@dataclass
class AgentConfig:
    """Learner hyperparameters, with Stable-Baselines3's names where one exists."""

    algorithm: Algorithm = Algorithm.dqn
    lr: float = 1e-3  # Adam step size (DQN) or alpha (tabular)
    gamma: float = 0.99  # discount
    batch_size: int = 64  # transitions per agent per gradient step
    buffer_size: int = 50_000  # replay capacity per agent
    learning_starts: int = 1_000  # env steps of pure collection before the first update
    train_freq: int = 1  # env steps between updates
    gradient_steps: int = 1  # gradient steps per update
    target_update: int = 1  # env steps between target-network updates (SB3's target_update_interval)
    tau: float = 0.01  # each target update: target <- tau*online + (1-tau)*target; 1.0 = hard copy
    hidden: List[int] = field(default_factory=lambda: [64, 64])  # MLP hidden sizes
    eps_start: float = 1.0  # initial exploration rate
    eps_end: float = 0.05  # final exploration rate
    exploration_fraction: float = 0.5  # fraction of total_steps over which epsilon decays linearly
    max_grad_norm: float = 10.0  # gradient-norm clip
    share_parameters: bool = False  # one network for all agents (parameter-sharing baseline)


@dataclass
class TransferConfig:
    """Warm start from a pretrained agent (DESIGN §6)."""

    enabled: bool = False
    source: Optional[str] = None  # checkpoint file or run directory; None: pretrain on TreasureHunt-v0
    source_agent: int = 0  # which agent_{i}.safetensors of a run directory
    pretrain_steps: int = 20_000  # env steps of source-task pretraining when no source is given
    cache_dir: Optional[str] = None  # pretrained-source cache; default <launch dir>/outputs/pretrained
    targets: Optional[List[int]] = None  # agents that receive the transfer; None: all
    reset_optimizer: bool = True  # start Adam moments afresh (the source's belong to another task)
    epsilon_start: float = 0.3  # transferred agents explore less than eps_start
    freeze: List[int] = field(default_factory=list)  # indices of layers kept fixed
    exchange: Exchange = Exchange.none  # knowledge exchange inside the team during training
    exchange_every: int = 20  # episodes between exchanges
    exchange_tau: float = 0.5  # 'best': weight of the best agent in the soft copy


@dataclass
class TrainConfig:
    env: EnvConfig = field(default_factory=EnvConfig)
    agent: AgentConfig = field(default_factory=AgentConfig)
    transfer: TransferConfig = field(default_factory=TransferConfig)
    seed: int = 0  # seeds the learners, exploration and episode resets
    total_steps: int = 30_000  # joint env steps (every live agent acts once)
    eval_every: int = 2_000  # env steps between greedy evaluations
    eval_episodes: int = 10
    checkpoint_every: int = 10_000  # env steps between checkpoints (written at the next episode end)
    progress: bool = True  # tqdm progress bar
    resume: bool = False  # continue the run in hydra.run.dir from its last checkpoint
    device: Device = Device.cpu
    threads: int = 1  # torch CPU threads: tiny networks run fastest on one, and sweep jobs don't oversubscribe


def register_configs() -> None:
    """Make the schemas available to ``conf/config.yaml`` (its defaults list names them)."""
    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)


class ConfigError(ValueError):
    """A configuration value that is well-typed but out of range."""


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


def validate(cfg: DictConfig | TrainConfig) -> None:
    """Range checks that types cannot express; raises ConfigError naming the key."""
    env, agent, transfer = cfg.env, cfg.agent, cfg.transfer
    _check(env.size >= 2, f"env.size must be >= 2, got {env.size}")
    _check(env.num_treasures >= 1, f"env.num_treasures must be >= 1, got {env.num_treasures}")
    _check(0.0 <= env.complexity < 1.0, f"env.complexity must be in [0, 1), got {env.complexity}")
    _check(env.max_steps is None or env.max_steps >= 1, f"env.max_steps must be >= 1, got {env.max_steps}")
    _check(env.view_radius >= 0, f"env.view_radius must be >= 0, got {env.view_radius}")
    _check(0.0 <= agent.gamma <= 1.0, f"agent.gamma must be in [0, 1], got {agent.gamma}")
    _check(agent.lr > 0, f"agent.lr must be > 0, got {agent.lr}")
    _check(agent.batch_size >= 1, f"agent.batch_size must be >= 1, got {agent.batch_size}")
    _check(agent.buffer_size >= 1, f"agent.buffer_size must be >= 1, got {agent.buffer_size}")
    _check(agent.learning_starts >= 0, f"agent.learning_starts must be >= 0, got {agent.learning_starts}")
    _check(agent.train_freq >= 1, f"agent.train_freq must be >= 1, got {agent.train_freq}")
    _check(agent.gradient_steps >= 1, f"agent.gradient_steps must be >= 1, got {agent.gradient_steps}")
    _check(agent.target_update >= 1, f"agent.target_update must be >= 1, got {agent.target_update}")
    _check(0.0 < agent.tau <= 1.0, f"agent.tau must be in (0, 1], got {agent.tau}")
    _check(len(agent.hidden) >= 1 and all(h >= 1 for h in agent.hidden),
           f"agent.hidden must be a non-empty list of positive sizes, got {list(agent.hidden)}")
    for key in ("eps_start", "eps_end", "exploration_fraction"):
        value = getattr(agent, key)
        _check(0.0 <= value <= 1.0, f"agent.{key} must be in [0, 1], got {value}")
    _check(agent.max_grad_norm > 0, f"agent.max_grad_norm must be > 0, got {agent.max_grad_norm}")
    _check(cfg.total_steps >= 0, f"total_steps must be >= 0, got {cfg.total_steps}")
    _check(cfg.eval_every >= 1, f"eval_every must be >= 1, got {cfg.eval_every}")
    _check(cfg.eval_episodes >= 1, f"eval_episodes must be >= 1, got {cfg.eval_episodes}")
    _check(cfg.checkpoint_every >= 1, f"checkpoint_every must be >= 1, got {cfg.checkpoint_every}")
    _check(cfg.threads >= 1, f"threads must be >= 1, got {cfg.threads}")
    _check(transfer.pretrain_steps >= 1, f"transfer.pretrain_steps must be >= 1, got {transfer.pretrain_steps}")
    _check(0.0 <= transfer.epsilon_start <= 1.0,
           f"transfer.epsilon_start must be in [0, 1], got {transfer.epsilon_start}")
    _check(transfer.exchange_every >= 1, f"transfer.exchange_every must be >= 1, got {transfer.exchange_every}")
    _check(0.0 < transfer.exchange_tau <= 1.0, f"transfer.exchange_tau must be in (0, 1], got {transfer.exchange_tau}")
    is_tabular = Algorithm(agent.algorithm) in TABULAR
    if is_tabular:
        _check(transfer.exchange == Exchange.none,
               f"transfer.exchange={Exchange(transfer.exchange).value} needs a DQN learner, not {Algorithm(agent.algorithm).value}")
        _check(not transfer.freeze, "transfer.freeze applies to network layers; tabular learners have none")
        _check(not agent.share_parameters, "agent.share_parameters applies to the DQN learners only")
    else:
        layers = len(agent.hidden) + 1
        _check(all(-layers <= i < layers for i in transfer.freeze),
               f"transfer.freeze={list(transfer.freeze)}: the network has {layers} layers (0..{layers - 1})")
    if agent.share_parameters:
        _check(transfer.targets is None, "transfer.targets: with agent.share_parameters=true all agents share one "
                                         "network, so all of them are transferred (leave targets unset)")
        _check(transfer.exchange != Exchange.best, "transfer.exchange=best: with agent.share_parameters=true "
                                                    "there is only one network to exchange")


def to_plain(cfg: DictConfig | TrainConfig) -> dict[str, Any]:
    """The config as plain JSON-able data (enums as their names), for meta, logs and hashes."""
    node = cfg if isinstance(cfg, DictConfig) else OmegaConf.structured(cfg)
    return OmegaConf.to_container(node, resolve=True, enum_to_str=True)  # type: ignore[return-value]

