"""Replica r of a batched learner as a team of its own: one way to batch replicas, for every learner.

Every learner is batched over R independent replicas of a team of K agents (rows ``r * K + k``; the
DQN family in one network module, the tabular learners as R x K tables), and is a lone team when
R = 1. The trainer runs each replica as a run of its own (run directory, checkpoints, evaluation,
transfer, exchange) through :func:`team_view`: replica r's K agents, with exactly the capabilities of
the learner (:class:`~dqn_transfer.agents.base.KnowledgeExchange`, :class:`~dqn_transfer.agents.base.WarmStart`,
:class:`~dqn_transfer.agents.visit_exchange.VisitExchange`).
A view reads and writes the learner's own values; nothing is copied.

What a view forwards to, :class:`ReplicaBatched`, is the learner's side: the team-wide methods take
``replica`` (the learner's rows of it), the per-agent ones a row.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, cast

import numpy as np

from dqn_transfer.agents.base import Experience, KnowledgeExchange, Learner, Team, WarmStart
from dqn_transfer.agents.visit_exchange import AdviceRules, VisitExchange


class ReplicaBatched(Protocol):
    """A learner's methods as a view calls them: of replica ``replica``, or of agent row ``row``."""

    num_replicas: int

    def act(
        self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray, replica: int | None = None
    ) -> np.ndarray: ...
    def best_actions(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray: ...
    def q_values(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray: ...
    def agent_tensors(self, row: int) -> dict[str, np.ndarray]: ...
    def load_agent_tensors(self, row: int, tensors: dict[str, np.ndarray]) -> None: ...
    def network_meta(self) -> dict[str, Any]: ...
    def training_state(self, replica: int = 0) -> tuple[dict[str, np.ndarray], dict[str, Any]]: ...
    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], replica: int = 0) -> None: ...


class ExchangeBatched(ReplicaBatched, Protocol):
    def soft_copy_best(self, best: int, tau: float, replica: int = 0) -> None: ...
    def learn_from(self, row: int, experience: Experience) -> None: ...


class VisitExchangeBatched(ReplicaBatched, Protocol):
    def merge_confident(self, weight: float, replica: int = 0) -> None: ...
    def start_advice(self, rules: AdviceRules, replica: int | None = None) -> None: ...


class WarmStartBatched(ReplicaBatched, Protocol):
    def freeze(self, layer_indices: Sequence[int]) -> None: ...
    def load_optimizer_state(self, row: int, moments: dict[str, dict[str, np.ndarray]], step: int) -> None: ...


class TeamView(Team):
    """Replica r of a batched learner: its K agents (agent i is the learner's row ``r * K + i``)."""

    def __init__(self, learner: Learner, r: int) -> None:
        if not 0 <= r < learner.num_replicas:
            raise IndexError(f"replica {r} out of range for {learner.num_replicas} replicas")
        self.batched, self.index, self.offset = cast(ReplicaBatched, learner), r, r * learner.num_agents
        self.algorithm, self.num_agents = learner.algorithm, learner.num_agents
        self.obs_layout, self.obs_dim, self.num_actions = learner.obs_layout, learner.obs_dim, learner.num_actions

    def _row(self, i: int) -> int:
        if not 0 <= i < self.num_agents:
            raise IndexError(f"agent index {i} out of range for {self.num_agents} agents")
        return self.offset + i

    def act(self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray) -> np.ndarray:
        return self.batched.act(obs, live, epsilon, replica=self.index)

    def best_actions(self, obs: np.ndarray) -> np.ndarray:
        return self.batched.best_actions(obs, replica=self.index)

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        return self.batched.q_values(obs, replica=self.index)

    def agent_tensors(self, i: int) -> dict[str, np.ndarray]:
        return self.batched.agent_tensors(self._row(i))

    def load_agent_tensors(self, i: int, tensors: dict[str, np.ndarray]) -> None:
        self.batched.load_agent_tensors(self._row(i), tensors)

    def network_meta(self) -> dict[str, Any]:
        return self.batched.network_meta()

    def training_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        return self.batched.training_state(self.index)

    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        self.batched.load_training_state(arrays, meta, self.index)


class _ExchangeView(TeamView, KnowledgeExchange):
    def soft_copy_best(self, best: int, tau: float) -> None:
        self._row(best)  # IndexError if not an agent of the team
        cast(ExchangeBatched, self.batched).soft_copy_best(best, tau, replica=self.index)

    def learn_from(self, i: int, experience: Experience) -> None:
        cast(ExchangeBatched, self.batched).learn_from(self._row(i), experience)


class _VisitExchangeView(TeamView, VisitExchange):
    def merge_confident(self, weight: float) -> None:
        cast(VisitExchangeBatched, self.batched).merge_confident(weight, replica=self.index)

    def start_advice(self, rules: AdviceRules) -> None:
        cast(VisitExchangeBatched, self.batched).start_advice(rules, replica=self.index)


class _WarmStartView(TeamView, WarmStart):
    def freeze(self, layer_indices: Sequence[int]) -> None:
        """Layers are stacked for all agents: freezing applies to every replica of the learner."""
        cast(WarmStartBatched, self.batched).freeze(layer_indices)

    def load_optimizer_state(self, i: int, moments: dict[str, dict[str, np.ndarray]], step: int) -> None:
        cast(WarmStartBatched, self.batched).load_optimizer_state(self._row(i), moments, step)


_CAPABILITY_VIEWS: tuple[tuple[type, type[TeamView]], ...] = (
    (KnowledgeExchange, _ExchangeView),
    (VisitExchange, _VisitExchangeView),
    (WarmStart, _WarmStartView),
)
_VIEW_CLASSES: dict[tuple[type[TeamView], ...], type[TeamView]] = {}


def team_view(learner: Learner, r: int) -> Team:
    """Replica r of ``learner`` as a :class:`~dqn_transfer.agents.base.Team` with the learner's capabilities."""
    mixins = tuple(view for capability, view in _CAPABILITY_VIEWS if isinstance(learner, capability))
    if mixins not in _VIEW_CLASSES:
        if not mixins:
            _VIEW_CLASSES[mixins] = TeamView
        elif len(mixins) == 1:
            _VIEW_CLASSES[mixins] = mixins[0]
        else:
            _VIEW_CLASSES[mixins] = type("TeamView", mixins, {"__doc__": TeamView.__doc__, "__module__": __name__})
    return _VIEW_CLASSES[mixins](learner, r)
