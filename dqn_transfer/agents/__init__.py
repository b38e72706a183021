"""Learners: tabular SARSA / Q-learning and batched DQN / Double DQN for a team of K agents.

``make_learner`` builds one from the ``agent`` config (:class:`~dqn_transfer.config.AgentConfig`, the
one home of every hyperparameter's default), ``make_replicas`` one batched over several seeds. What a
learner can do is a set of capabilities (:mod:`dqn_transfer.agents.base`): every learner is a
:class:`Learner` (acting, learning, checkpointing, batched over replicas) and implements
:class:`KnowledgeExchange`; the DQN family also :class:`WarmStart` (freezing layers, carrying optimizer
state over), :class:`ExperienceSharing` (``transfer.exchange=experience``) and the tabular one
:class:`VisitExchange` (exchange by visit counts: confidence, advice). Code outside this package calls these
methods, never a learner's class; the run's plan has checked that its learner family has them.

The DQN family has two engines (``agent.engine``, whose default ``auto`` means numpy on the CPU and
torch on a GPU): ``torch`` (:mod:`~dqn_transfer.agents.dqn`) and ``numpy``
(:mod:`~dqn_transfer.agents.numpy_dqn`, a CPU fast path for DQN, Double DQN and VDN), which share
:mod:`~dqn_transfer.agents.dqn_update` (the target, the loss and the clip rule; no torch import). An
engine's module is imported when a learner of it is built, so that a process that trains a tabular or
numpy learner never imports torch (3-4 s of start-up); the torch engine's names below
(``DQNLearner``, ``BatchedMLP``, ...) are imported on first use.
"""

from __future__ import annotations

from collections.abc import Sequence
from importlib import import_module
from typing import Any

from dqn_transfer.agents.base import (
    Acting,
    Checkpointing,
    Experience,
    ExperienceSharing,
    KnowledgeExchange,
    Learner,
    Learning,
    ObsLayout,
    Team,
    Transition,
    UpdateStats,
    WarmStart,
    break_ties,
    epsilon_greedy,
    joined,
)
from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.agents.dqn_update import double_dqn_targets, dqn_targets
from dqn_transfer.agents.replay import ReplayBatch, ReplayBuffer
from dqn_transfer.agents.replicas import TeamView, team_view
from dqn_transfer.agents.schedules import linear_schedule
from dqn_transfer.agents.state_index import StateCode
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.agents.visit_exchange import AdviceRules, VisitExchange
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm, Device, Engine, resolve_engine

# The torch engine's public names, by module (imported on first access: see __getattr__).
_TORCH_NAMES = {
    "DQNLearner": "dqn_transfer.agents.dqn",
    "BatchedMLP": "dqn_transfer.agents.networks",
}

__all__ = [
    "Acting",
    "AdviceRules",
    "BatchedDQN",
    "BatchedMLP",
    "Checkpointing",
    "DQNLearner",
    "Experience",
    "ExperienceSharing",
    "KnowledgeExchange",
    "Learner",
    "Learning",
    "ReplayBatch",
    "ReplayBuffer",
    "StateCode",
    "TabularLearner",
    "Team",
    "TeamView",
    "Transition",
    "UpdateStats",
    "VisitExchange",
    "WarmStart",
    "break_ties",
    "check_device",
    "double_dqn_targets",
    "dqn_targets",
    "epsilon_greedy",
    "joined",
    "linear_schedule",
    "make_learner",
    "make_replicas",
    "team_view",
]


def __getattr__(name: str) -> Any:
    if name in _TORCH_NAMES:
        return getattr(import_module(_TORCH_NAMES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def check_device(device: Device | str) -> None:
    """Refuse ``device=cuda`` where torch sees no CUDA device, when the run is planned (torch is imported
    for that device only)."""
    if Device(device) is Device.cuda:
        import_module("dqn_transfer.agents.dqn").resolve_device(device)


def make_learner(
    hp: AgentConfig,
    num_agents: int,
    obs_layout: ObsLayout,
    num_actions: int,
    seed: int,
    device: Device | str = "cpu",
    threads: int | None = None,
) -> Learner:
    """The learner ``hp.algorithm`` names, for ``num_agents`` agents (one replica: its rows are the agents).

    ``seed`` fixes the initial weights and every random draw the learner makes (exploration,
    replay sampling, tie-breaking). Raises ``ValueError`` for an unknown algorithm.
    """
    return make_replicas(hp, num_agents, obs_layout, num_actions, [seed], device, threads)


def make_replicas(
    hp: AgentConfig,
    num_agents: int,
    obs_layout: ObsLayout,
    num_actions: int,
    seeds: Sequence[int],
    device: Device | str = "cpu",
    threads: int | None = None,
    code: StateCode | None = None,
) -> Learner:
    """One replica of ``num_agents`` agents per seed, in one learner (rows ``r * K + k``, ``replica(r)``
    its team): for the DQN family one network module holds every replica, for the tabular ones
    ``R x K`` tables. Replica r is exactly the learner ``make_learner`` builds for ``seeds[r]``.

    ``device`` (cpu | cuda | auto) and ``threads`` (torch's CPU threads; None: as they are) concern the torch engine;
    the numpy engine and the tabular learners run on the CPU. Raises ``ConfigError`` for a device
    that is not there. ``code`` is the games' numbering of their observations, if they have one: the
    tabular learners then hold dense tables (:mod:`~dqn_transfer.agents.state_index`).
    """
    if Algorithm(hp.algorithm).is_tabular:
        return TabularLearner(num_agents, obs_layout, num_actions, hp, seed=list(seeds), code=code)
    if resolve_engine(hp.engine, device, hp.algorithm, hp.mixer) is Engine.numpy:
        engine = import_module("dqn_transfer.agents.numpy_dqn")
        return engine.NumpyDQNLearner(num_agents, obs_layout, num_actions, hp, seed=list(seeds))
    engine = import_module("dqn_transfer.agents.dqn")
    return engine.DQNLearner(
        num_agents, obs_layout, num_actions, hp, seed=list(seeds), device=engine.resolve_device(device, threads)
    )
