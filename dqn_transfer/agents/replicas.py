"""R independent learners behind one batched interface, for learners without a batched module.

The DQN family batches replicas inside one network module (``DQNLearner`` with a list of seeds);
tabular tables have nothing to batch, so their replicas are simply stepped one after the other.
Both present the trainer the same face: rows ``r * K + k`` in, rows out, and :meth:`replica` for
replica r's team as a ``Learner`` of its own.
"""

from __future__ import annotations

import numpy as np

from dqn_transfer.agents.base import Learner, Transition, UpdateStats


class LearnerReplicas:
    """``learners[r]`` is replica r, a team of K agents; every array is ``[R * K, ...]``, replica-major."""

    def __init__(self, learners: list[Learner]) -> None:
        self.learners = learners
        first = learners[0]
        self.algorithm, self.num_agents = first.algorithm, first.num_agents
        self.obs_layout, self.num_actions = first.obs_layout, first.num_actions
        self.num_replicas = len(learners)
        self.num_rows = self.num_replicas * self.num_agents

    def replica(self, r: int) -> Learner:
        return self.learners[r]

    def _rows(self, r: int) -> slice:
        return slice(r * self.num_agents, (r + 1) * self.num_agents)

    def act(
        self,
        obs: np.ndarray,
        live: np.ndarray,
        epsilon: float | np.ndarray,
        greedy: bool = False,
        ties: np.random.Generator | None = None,
    ) -> np.ndarray:
        epsilon = np.asarray(epsilon, dtype=np.float64)
        if epsilon.ndim == 0:
            epsilon = np.full(self.num_rows, epsilon)
        return np.concatenate(
            [
                learner.act(obs[self._rows(r)], live[self._rows(r)], epsilon[self._rows(r)], greedy, ties)
                for r, learner in enumerate(self.learners)
            ]
        )

    def update(self, transition: Transition, step: int) -> UpdateStats:
        stats = [
            learner.update(Transition(*(field[self._rows(r)] for field in transition)), step)
            for r, learner in enumerate(self.learners)
        ]
        return UpdateStats(*(np.concatenate(column) for column in zip(*stats)))
