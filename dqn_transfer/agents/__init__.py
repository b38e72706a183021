"""Learners: tabular SARSA / Q-learning and batched DQN / Double DQN for a team of K agents.

``make_learner`` builds one from the ``agent`` config (:class:`~dqn_transfer.config.AgentConfig`, the
one home of every hyperparameter's default). Every learner implements
:class:`~dqn_transfer.agents.base.Learner`; the DQN family adds ``freeze``, ``set_member_optimizer_state``,
``get_member_weights`` / ``set_member_weights`` and ``add_experience``, the tabular one ``set_fallback``.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from dqn_transfer.agents.base import Learner, ObsLayout, Transition, UpdateStats, epsilon_greedy
from dqn_transfer.agents.dqn import DQNLearner, DQNReplica, double_dqn_targets, dqn_targets
from dqn_transfer.agents.networks import BatchedMLP
from dqn_transfer.agents.replay import ReplayBatch, ReplayBuffer
from dqn_transfer.agents.replicas import LearnerReplicas
from dqn_transfer.agents.schedules import linear_schedule
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm

__all__ = [
    "BatchedMLP",
    "DQNLearner",
    "DQNReplica",
    "LearnerReplicas",
    "Learner",
    "ReplayBatch",
    "ReplayBuffer",
    "TabularLearner",
    "Transition",
    "UpdateStats",
    "double_dqn_targets",
    "dqn_targets",
    "epsilon_greedy",
    "linear_schedule",
    "make_learner",
    "make_replicas",
]


def make_learner(
    hp: AgentConfig,
    num_agents: int,
    obs_layout: ObsLayout,
    num_actions: int,
    seed: int,
    device: torch.device | str = "cpu",
) -> Learner:
    """The learner ``hp.algorithm`` names, for ``num_agents`` agents.

    ``seed`` fixes the initial weights and every random draw the learner makes (exploration,
    replay sampling, tie-breaking). Raises ``ValueError`` for an unknown algorithm.
    """
    if Algorithm(hp.algorithm).is_tabular:
        return TabularLearner(num_agents, obs_layout, num_actions, hp, seed=seed)
    return DQNLearner(num_agents, obs_layout, num_actions, hp, seed=seed, device=device)


def make_replicas(
    hp: AgentConfig,
    num_agents: int,
    obs_layout: ObsLayout,
    num_actions: int,
    seeds: Sequence[int],
    device: torch.device | str = "cpu",
) -> DQNLearner | LearnerReplicas:
    """One replica of ``num_agents`` agents per seed, behind one batched interface (rows ``r * K + k``,
    ``replica(r)``): for the DQN family one ``DQNLearner`` whose network module holds every replica,
    for the tabular ones a :class:`LearnerReplicas` of separate learners. Replica r is exactly the
    learner ``make_learner`` builds for ``seeds[r]``."""
    if Algorithm(hp.algorithm).is_tabular:
        return LearnerReplicas([TabularLearner(num_agents, obs_layout, num_actions, hp, seed=s) for s in seeds])
    return DQNLearner(num_agents, obs_layout, num_actions, hp, seed=list(seeds), device=device)
