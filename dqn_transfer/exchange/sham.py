"""``transfer.exchange=sham``, the negative control of ``shared_replay``: the same schedule and the same
volume, without the knowledge. Every ``exchange_every`` episodes each agent learns, through the same
``learn_from``, from exactly as many transitions as ``shared_replay`` would hand it (its team-mates'
moves of the window but their obstacle bounces), taken from its own moves of the window instead, in
order and cycled. What the agent learns from is its own experience again: the extra replay writes
(DQN) or table updates (SARSA, Q-learning) that an exchange costs, and nothing a team-mate knows. An
agent that did not move in the window receives nothing.

A study compares an exchange with ``none`` to ask whether it helps, and with ``sham`` to ask whether
what helps is the knowledge or merely the volume of learning it brings.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np

from dqn_transfer.agents import Experience, KnowledgeExchange, Team, Transition
from dqn_transfer.exchange.shared_replay import SharedReplay, window_experience


def sham_replay(team: Team, transitions: Sequence[Transition], bounced: Sequence[np.ndarray]) -> None:
    """Each agent learns from its own moves of the window, as many as its team-mates' moves together;
    ``bounced[t]``, ``bool [K]``: who moved into an obstacle on step ``t`` (not a move to learn from)."""
    if not transitions:
        return
    exchange = cast(KnowledgeExchange, team)
    own = window_experience(transitions, bounced)
    sizes = [len(experience.actions) for experience in own]
    for receiver, experience in enumerate(own):
        volume = sum(sizes) - sizes[receiver]  # what shared_replay would give it
        if volume and sizes[receiver]:
            rows = np.resize(np.arange(sizes[receiver]), volume)  # its own moves in order, cycled
            exchange.learn_from(receiver, Experience(*(column[rows] for column in experience)))


class ShamReplay(SharedReplay):
    name = "sham"

    def share(self, team: Team, transitions: Sequence[Transition], bounced: Sequence[np.ndarray]) -> None:
        sham_replay(team, transitions, bounced)
