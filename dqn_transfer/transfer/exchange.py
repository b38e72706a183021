"""Team knowledge exchange during training (``transfer.exchange``), once every ``exchange_every`` episodes.

- ``best``: every other agent moves its values ``exchange_tau`` of the way to the agent with the
  highest mean episodic return over the window (a soft copy). A network's weights move (layers kept
  fixed stay as they are); a table's entries move, over every state either table holds;
- ``shared_replay``: each agent learns from its team-mates' transitions of the window, except their
  obstacle bounces. A DQN agent receives them into its replay; a table, which has no replay, is updated
  on each of them once, by its own rule (SARSA draws the next action from its own epsilon-greedy policy).
  A move into an obstacle sends the mover back to its own start, and no two agents of a map share a
  start cell, so a team-mate's bounce would teach an agent that the move leads to somebody else's start
  (SEQL's experience sharing likewise leaves out the agent-specific transition).

Both go through the learner's :class:`~dqn_transfer.agents.KnowledgeExchange` capability
(``soft_copy_best``, ``learn_from``): each learner family implements its own semantics.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dqn_transfer.agents import Experience, KnowledgeExchange, Team, Transition, require


def exchange_best(team: Team, window_returns: np.ndarray, tau: float) -> int:
    """Soft-copy the best agent into the others; returns the best agent's index.

    ``window_returns [episodes, K]``: each agent's episodic return over the window.
    """
    best = int(np.argmax(window_returns.mean(axis=0)))
    require(team, KnowledgeExchange, "transfer.exchange=best").soft_copy_best(best, tau)
    return best


def exchange_replay(team: Team, transitions: Sequence[Transition], bounced: Sequence[np.ndarray]) -> None:
    """Each agent learns from its team-mates' transitions of the window but their obstacle bounces (see
    the module docstring); ``bounced[t]``, ``bool [K]``: who moved into an obstacle on step ``t``."""
    exchange = require(team, KnowledgeExchange, "transfer.exchange=shared_replay")
    if not transitions:
        return
    window = Transition(*(np.stack(column) for column in zip(*transitions)))  # fields [T, K, ...]
    bounces = np.stack(bounced)  # [T, K]
    for giver in range(team.num_agents):
        taken = window.live[:, giver] & ~bounces[:, giver]  # the giver's moves, but its bounces
        experience = Experience(
            *(
                column[taken, giver]
                for column in (window.obs, window.actions, window.rewards, window.next_obs, window.terminated)
            )
        )
        for receiver in range(team.num_agents):
            if receiver != giver:
                exchange.learn_from(receiver, experience)
