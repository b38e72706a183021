"""Knowledge exchange by visit counts, for tables: confidence-weighted merging and action advising.

A table learner counts, per agent and state, the updates the agent made there on its own transitions
(its *visits*; updates from team-mates' transitions, merges and warm starts are not its experience
and do not count). Two exchanges read these counts (``transfer.exchange``, docs/transfer.md):

- ``confidence`` (Tan 1993, "Multi-agent reinforcement learning: independent vs. cooperative agents"):
  every agent i moves its values of a state toward the team-mate j that visited it most, only where
  ``n_j(s) > n_i(s)``, by ``w = weight * n_j(s) / (n_i(s) + n_j(s))``:
  ``Q_i(s) <- Q_i(s) + w (Q_j(s) - Q_i(s))``. All agents merge at once, from the values before the merge.
- ``advice`` (Torrey & Taylor 2013, "Teaching on a budget"; da Silva et al. 2017, "Simultaneously
  learning and advising"): an agent that visited its state fewer than ``ask_below`` times asks, and
  the team-mate that visited that state most answers if it did at least ``answer_from`` times: its
  greedy action replaces the student's, while the student's budget of advised steps lasts.

Ties go to the lowest index, both among team-mates and among an advisor's best actions, so neither
takes a random number: a run whose agents are never advised is the run without advice, bit for bit.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np


class AdviceRules(NamedTuple):
    """When an agent is advised (``transfer.advice_*``)."""

    ask_below: int  # the student asks when it visited its state fewer times than this
    answer_from: int  # the team-mate that visited the state most answers if it visited it at least this often
    budget: int  # advised steps per agent per run


class VisitExchange(ABC):
    """Exchange that reads each agent's visit counts of the team's states (the tabular learners)."""

    @abstractmethod
    def merge_confident(self, weight: float) -> None:
        """Every agent merges its most-visiting team-mate's values on the states that team-mate visited more
        (see the module docstring); ``weight`` in (0, 1] scales the merge weight."""

    @abstractmethod
    def start_advice(self, rules: AdviceRules) -> None:
        """From now on, training's exploring actions take advice by ``rules``; every agent's budget is full."""


def most_visited_mates(visits: np.ndarray) -> np.ndarray:
    """``visits [K, S]`` -> ``[K, S]``: for each agent and state, the team-mate that visited the state
    most, the lowest index on a tie (an agent alone gets itself, which never counts as more)."""
    k = visits.shape[0]
    mates = np.broadcast_to(visits, (k, *visits.shape)).copy()  # [agent, team-mate, S]
    mates[np.arange(k), np.arange(k)] = -1  # an agent is not its own team-mate
    return mates.argmax(axis=1)


def confident_merge(q: np.ndarray, visits: np.ndarray, weight: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One team's confidence-weighted merge: ``q [K, S, A]`` float32 and ``visits [K, S]`` -> the merged
    values, ``merged [K, S]`` (the entries that moved toward a team-mate) and ``source [K, S]`` (that
    team-mate). Where a team-mate visited a state more, ``w = weight * n_j / (n_i + n_j)``."""
    source = most_visited_mates(visits)  # [K, S]
    states = np.arange(visits.shape[1])
    mate_visits = visits[source, states]
    merged = mate_visits > visits
    share = weight * mate_visits / np.maximum(visits + mate_visits, 1)
    moved = q + share[..., None] * (q[source, states] - q)
    return np.where(merged[..., None], moved, q).astype(np.float32), merged, source


def advised_actions(
    team_visits: np.ndarray, own: np.ndarray, advisor_values: np.ndarray, rules: AdviceRules
) -> tuple[np.ndarray, np.ndarray]:
    """Who is advised, and the advice, for N students each on its own state.

    :param team_visits: ``[N, K]`` the visits of each student's state by every agent of its team
    :param own: ``[N]`` each student's index in its team
    :param advisor_values: ``[N, K, A]`` every team agent's values of the student's state
    :param rules: the thresholds (the budget is the caller's)
    :returns: ``advised [N]`` bool (asked, and answered) and ``advice [N]``, the most-visiting team-mate's
        greedy action (the lowest of tied best actions)
    """
    n = np.arange(len(own))
    mates = team_visits.copy()
    mates[n, own] = -1  # a student never answers itself
    advisor = mates.argmax(axis=1)  # the lowest index on a tie
    asked = team_visits[n, own] < rules.ask_below
    advised = asked & (mates[n, advisor] >= rules.answer_from)
    return advised, advisor_values[n, advisor].argmax(axis=1)
