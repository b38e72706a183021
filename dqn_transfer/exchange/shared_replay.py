"""``transfer.exchange=shared_replay``: every ``exchange_every`` episodes, each agent learns from its
team-mates' transitions of the window, except their obstacle bounces. A DQN agent receives them into
its replay; a table, which has no replay, is updated on each of them once, by its own rule (SARSA draws
the next action from its own epsilon-greedy policy). A move into an obstacle sends the mover back to its
own start, and no two agents of a map share a start cell, so a team-mate's bounce would teach an agent
that the move leads to somebody else's start (SEQL's experience sharing likewise leaves out the
agent-specific transition). The window is kept per replica and saved with checkpoints.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from dqn_transfer.agents import Experience, KnowledgeExchange, Team, Transition
from dqn_transfer.config import TransferConfig
from dqn_transfer.exchange.base import ExchangeMethod


def window_experience(transitions: Sequence[Transition], bounced: Sequence[np.ndarray]) -> list[Experience]:
    """Each agent's moves of the window, but its obstacle bounces (``bounced[t]``, ``bool [K]``: who moved
    into an obstacle on step ``t``); empty ones for an empty window."""
    window = Transition(*(np.stack(column) for column in zip(*transitions)))  # fields [T, K, ...]
    bounces = np.stack(bounced)  # [T, K]
    num_agents = bounces.shape[1]
    fields = (window.obs, window.actions, window.rewards, window.next_obs, window.terminated)
    taken = window.live & ~bounces
    return [Experience(*(column[taken[:, agent], agent] for column in fields)) for agent in range(num_agents)]


def exchange_replay(team: Team, transitions: Sequence[Transition], bounced: Sequence[np.ndarray]) -> None:
    """Each agent learns from its team-mates' transitions of the window but their obstacle bounces;
    ``bounced[t]``, ``bool [K]``: who moved into an obstacle on step ``t``."""
    if not transitions:
        return
    exchange = cast(KnowledgeExchange, team)
    for giver, experience in enumerate(window_experience(transitions, bounced)):
        for receiver in range(team.num_agents):
            if receiver != giver:
                exchange.learn_from(receiver, experience)


class SharedReplay(ExchangeMethod):
    name = "shared_replay"
    moves_transitions = fills_replays = at_interval = True

    def __init__(self, transfer: TransferConfig, num_replicas: int) -> None:
        super().__init__(transfer, num_replicas)
        self.transitions: list[list[Transition]] = [[] for _ in range(num_replicas)]  # each replica's window
        self.bounced: list[list[np.ndarray]] = [[] for _ in range(num_replicas)]  # who bounced at each step

    def after_step(self, transition: Transition, bounced: np.ndarray) -> None:
        k = bounced.shape[1]
        for r, window in enumerate(self.transitions):
            window.append(Transition(*(column[r * k : (r + 1) * k] for column in transition)))
            self.bounced[r].append(bounced[r])

    def exchange(self, r: int, team: Team, returns: np.ndarray) -> list[tuple[str, float]]:
        self.share(team, self.transitions[r], self.bounced[r])
        self.transitions[r].clear()
        self.bounced[r].clear()
        return []

    def share(self, team: Team, transitions: Sequence[Transition], bounced: Sequence[np.ndarray]) -> None:
        """What the agents of ``team`` learn from a window (:func:`exchange_replay`)."""
        exchange_replay(team, transitions, bounced)

    def state(self, r: int) -> dict[str, np.ndarray]:
        arrays = {name: np.stack(column) for name, column in zip(Transition._fields, zip(*self.transitions[r]))}
        if self.bounced[r]:
            arrays["bounced"] = np.stack(self.bounced[r])
        return arrays

    def load_state(self, r: int, arrays: dict[str, Any], num_agents: int) -> None:
        if "obs" not in arrays:
            return
        self.transitions[r] = [Transition(*fields) for fields in zip(*(arrays[name] for name in Transition._fields))]
        # A checkpoint written before bounces were recorded: its window is shared whole, as it was then.
        unrecorded = np.zeros((len(self.transitions[r]), num_agents), dtype=bool)
        self.bounced[r] = list(arrays.get("bounced", unrecorded))
