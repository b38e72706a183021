"""The closed vocabularies of the project, each spelled once.

The game, the learners, the config schemas, the checkpoint files and the analysis all name modes,
algorithms and exchange kinds by these enums' values; nothing else in the package spells them. The
module imports nothing, so every layer (down to the game) may use it.
"""

from __future__ import annotations

from enum import Enum
from typing import TypeVar


class Mode(Enum):
    """How the ``treasures`` belief is kept: no communication, announcements, a coordinator."""

    competitive = "competitive"
    cooperative = "cooperative"
    deliberative = "deliberative"


class RewardMode(Enum):
    """``individual``: each agent its own reward; ``team``: every live agent the step's sum."""

    individual = "individual"
    team = "team"


class ObsEncoding(Enum):
    """The ``position`` segment: one-hot of the cell, or its two normalised coordinates."""

    onehot = "onehot"
    coords = "coords"


class Contention(Enum):
    """Which generated maps a map seed may give, by their contention for the agents' nearest chests
    (docs/game.md): ``any`` map, ``high`` (every agent's nearest chest is also another's) or ``low``
    (every agent's nearest chest is its own)."""

    any = "any"
    high = "high"
    low = "low"


class Algorithm(Enum):
    sarsa = "sarsa"
    qlearning = "qlearning"
    dqn = "dqn"
    double_dqn = "double_dqn"

    @property
    def is_tabular(self) -> bool:
        return self in (Algorithm.sarsa, Algorithm.qlearning)

    @property
    def family(self) -> str:
        """``tabular`` or ``dqn``: a checkpoint transfers within its family (a DQN network may
        continue as Double DQN, a SARSA table as Q-learning)."""
        return "tabular" if self.is_tabular else "dqn"


class Exchange(Enum):
    """Team knowledge exchange during training."""

    none = "none"
    best = "best"  # the others soft-copy the best agent's weights
    shared_replay = "shared_replay"  # team-mates' transitions go into each agent's replay
    experience = "experience"  # DQN: each gradient step also on team-mates' replay samples (SEAC's shared experience)
    confidence = "confidence"  # tables: merge a team-mate's values on the states it visited more (Tan 1993)
    advice = "advice"  # tables: a rarely-visited state's action comes from the most experienced team-mate
    sham = "sham"  # control: shared_replay's schedule and volume, each agent's own transitions again


class Mixer(Enum):
    """How the DQN learners combine the agents' Q-values into what is trained (``agent.mixer``)."""

    none = "none"  # each agent on its own TD error
    vdn = "vdn"  # the team: Q_tot = sum of the live agents' Q-values on the sum of their rewards (Sunehag et al. 2018)


class Device(Enum):
    cpu = "cpu"
    cuda = "cuda"
    auto = "auto"


class Objective(Enum):
    """What ``python train.py`` returns to a Hydra sweeper (Optuna): the evaluated team return's ``final``
    value (the last evaluation) or its ``mean`` over all evaluations; a run of replicas, their mean."""

    final = "final"
    mean = "mean"


class Engine(Enum):
    """What computes the DQN learners: ``torch`` (any device), ``numpy`` (CPU, no torch in the process)
    or ``auto`` (numpy for ``device=cpu`` and a loss it implements, else torch: see :func:`resolve_engine`)."""

    auto = "auto"
    torch = "torch"
    numpy = "numpy"


# The losses the numpy engine implements (each agent.algorithm with each agent.mixer listed); any other runs on
# torch, where the update is stated with autograd (dqn_transfer.agents.dqn).
NUMPY_ALGORITHMS = (Algorithm.dqn, Algorithm.double_dqn)
NUMPY_MIXERS = (Mixer.none, Mixer.vdn)


def numpy_implements(algorithm: Algorithm | str, mixer: Mixer | str) -> bool:
    """Whether the numpy engine implements the loss of ``agent.algorithm`` with ``agent.mixer``."""
    return Algorithm(algorithm) in NUMPY_ALGORITHMS and Mixer(mixer) in NUMPY_MIXERS


def resolve_engine(
    engine: Engine | str, device: Device | str, algorithm: Algorithm | str, mixer: Mixer | str
) -> Engine:
    """The engine ``agent.engine`` means on ``device`` for ``agent.algorithm`` and ``agent.mixer``: ``auto``
    is numpy on the CPU for a loss it implements (2-5x torch's update speed on this project's small networks, no
    torch import), torch otherwise."""
    engine = Engine(engine)
    if engine is not Engine.auto:
        return engine
    return Engine.numpy if Device(device) is Device.cpu and numpy_implements(algorithm, mixer) else Engine.torch


class Logger(Enum):
    """Where a run's scalars, evaluation pictures and config go (``logger``; several at once)."""

    tensorboard = "tensorboard"  # tb/ event files
    csv = "csv"  # scalars.csv: step, tag, value
    wandb = "wandb"  # Weights & Biases (the optional ``wandb`` extra); WANDB_MODE=offline works without an account


class Fill(Enum):
    """What a transferred network reads at target cells outside the embedded source map (``transfer.fill``)."""

    zero = "zero"  # zero input weights: the cell is unknown to the source
    nearest = "nearest"  # the weights of the nearest embedded cell (the source map's border, extended)


class SourceTask(Enum):
    """What a pretrained transfer source is trained on (``transfer.source_task``)."""

    single = "single"  # TreasureHunt-v0: the single-agent MDP of the map (agent 0 alone)
    per_agent = "per_agent"  # TreasureHunt-v0 from each target agent's own start: one source per target
    team = "team"  # the run's own multi-agent game; the targets start from one of its members


class Bound(Enum):
    """A scripted reference team drawn beside the learners (``evaluation/bounds.py``, docs/bounds.md)."""

    oracle = "oracle"  # the whole map known, agents matched to chests for the least total distance
    greedy = "greedy"  # each agent to its nearest chest believed full, no coordination
    random = "random"  # each agent a uniformly random action every step: a normalised score's zero


def values(enum: type[Enum]) -> tuple[str, ...]:
    """The accepted spellings of an enum, in declaration order (for checks and messages)."""
    return tuple(member.value for member in enum)


E = TypeVar("E", bound=Enum)


def check_choice(name: str, value: object, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}; got {value!r}")
    return value


def check_enum(name: str, value: object, enum: type[E]) -> E:
    """``value`` as a member of ``enum``: a member, or its spelling (the faces take strings)."""
    if isinstance(value, enum):
        return value
    return enum(check_choice(name, value, values(enum)))


class Extra(Enum):
    """The optional dependencies of pyproject.toml a feature needs (``pip install "dqn_transfer[EXTRA]"``)."""

    envs = "envs"
    sweep = "sweep"
    slurm = "slurm"
    optuna = "optuna"
    wandb = "wandb"

    @property
    def install(self) -> str:
        """The command that installs it."""
        return f'pip install "dqn_transfer[{self.value}]"'


# The module each extra brings, as an ImportError names it (``err.name``): a missing one says what to install.
EXTRA_MODULES = {
    "lbforaging": Extra.envs,
    "mpe2": Extra.envs,
    "hydra_plugins.hydra_joblib_launcher": Extra.sweep,
    "hydra_plugins.hydra_submitit_launcher": Extra.slurm,
    "submitit": Extra.slurm,
    "hydra_plugins.hydra_optuna_sweeper": Extra.optuna,
    "optuna": Extra.optuna,
    "wandb": Extra.wandb,
}
# A Hydra plugin chosen on the command line (group, option prefix) -> the module it lives in.
HYDRA_PLUGINS = {
    ("hydra/launcher", "joblib"): "hydra_plugins.hydra_joblib_launcher",
    ("hydra/launcher", "submitit"): "hydra_plugins.hydra_submitit_launcher",
    ("hydra/sweeper", "optuna"): "hydra_plugins.hydra_optuna_sweeper",
}
