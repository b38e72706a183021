"""Learners: tabular SARSA / Q-learning and batched DQN / Double DQN for a team of K agents.

``make_learner`` builds one from the ``agent`` config group. Every learner implements
:class:`~dqn_transfer.agents.base.Learner`; the DQN family adds ``freeze``, ``set_member_optimizer_state``,
``get_member_weights`` / ``set_member_weights`` and its ``replay`` buffer, the tabular one
``set_fallback``.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from enum import Enum
from typing import Any

import numpy as np
import torch

from dqn_transfer.agents.base import Learner, ObsLayout, epsilon_greedy
from dqn_transfer.agents.dqn import DQNLearner, double_dqn_targets, dqn_targets
from dqn_transfer.agents.networks import BatchedMLP
from dqn_transfer.agents.replay import ReplayBuffer
from dqn_transfer.agents.schedules import linear_schedule
from dqn_transfer.agents.tabular import TabularLearner

ALGORITHMS = ("sarsa", "qlearning", "dqn", "double_dqn")

__all__ = [
    "ALGORITHMS",
    "BatchedMLP",
    "DQNLearner",
    "Learner",
    "ReplayBuffer",
    "TabularLearner",
    "double_dqn_targets",
    "dqn_targets",
    "epsilon_greedy",
    "linear_schedule",
    "make_learner",
]
# Constructor keywords that come from make_learner's own arguments, never from the config.
_SET_BY_MAKE_LEARNER = ("double", "rng", "seed", "device")


def _hyperparameters(agent_cfg: Mapping[str, Any], learner: type) -> dict[str, Any]:
    """The config entries the learner's constructor takes as keywords; others (eps_*, ...) belong
    to the trainer. Lists come back as plain lists (Hydra gives ListConfig)."""
    accepted = {
        name
        for name, parameter in inspect.signature(learner).parameters.items()
        if parameter.kind is inspect.Parameter.KEYWORD_ONLY and name not in _SET_BY_MAKE_LEARNER
    }
    return {
        key: list(value) if key == "hidden" else value for key, value in agent_cfg.items() if key in accepted
    }


def make_learner(
    agent_cfg: Mapping[str, Any],
    num_agents: int,
    obs_layout: ObsLayout,
    num_actions: int,
    seed: int,
    device: torch.device | str = "cpu",
) -> Learner:
    """Build the learner named by ``agent_cfg["algorithm"]`` for ``num_agents`` agents.

    ``seed`` fixes the initial weights and every random draw the learner makes (exploration,
    replay sampling, tie-breaking). Raises ``ValueError`` for an unknown algorithm.
    """
    algorithm = agent_cfg["algorithm"]
    algorithm = str(algorithm.value if isinstance(algorithm, Enum) else algorithm)
    if algorithm in ("sarsa", "qlearning"):
        return TabularLearner(
            algorithm,
            num_agents,
            obs_layout,
            num_actions,
            rng=np.random.default_rng(seed),
            **_hyperparameters(agent_cfg, TabularLearner),
        )
    if algorithm in ("dqn", "double_dqn"):
        return DQNLearner(
            num_agents,
            obs_layout,
            num_actions,
            double=algorithm == "double_dqn",
            seed=seed,
            device=device,
            **_hyperparameters(agent_cfg, DQNLearner),
        )
    raise ValueError(f"unknown agent.algorithm {algorithm!r}; expected one of {list(ALGORITHMS)}")
