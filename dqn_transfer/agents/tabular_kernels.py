"""The tabular learners' inner loops, compiled (numba, plain loops over rows): the epsilon-greedy
choice and the table update.

Each kernel does the arithmetic the learner states (:mod:`~dqn_transfer.agents.tabular`) in the same
types, one row after another: float32 values and targets, float64 uniforms and epsilon. So a run's
numbers are those of the vectorised numpy statement, bit for bit (tests check the kernels against it).
"""

from __future__ import annotations

import math

import numpy as np

from dqn_transfer.compiled import kernel


@kernel
def choose_action(values: np.ndarray, epsilon: float, draws: np.ndarray) -> int:
    """One epsilon-greedy choice on ``values [A]``: a uniformly random action if ``draws[0] < epsilon``
    (``floor(draws[1] * A)``), else the ``floor(draws[2] * ties)``-th of the tied best actions."""
    num_actions = len(values)
    if draws[0] < epsilon:
        return int(math.floor(draws[1] * num_actions))
    best = values.max()
    ties = 0
    for a in range(num_actions):
        if values[a] == best:
            ties += 1
    pick = int(math.floor(draws[2] * ties))
    for a in range(num_actions):
        if values[a] == best:
            if pick == 0:
                return a
            pick -= 1
    return num_actions - 1  # not reached: pick < ties


@kernel
def epsilon_greedy_rows(q: np.ndarray, epsilon: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Per row of ``q [N, A]``: with probability ``epsilon [N]`` a uniformly random action, else a best
    action, ties going to a uniformly drawn one of them; ``draws [N, 3]`` uniforms in ``[0, 1)`` (one
    per choice, always all three)."""
    actions = np.empty(len(q), dtype=np.int64)
    for n in range(len(q)):
        actions[n] = choose_action(q[n], epsilon[n], draws[n])
    return actions


@kernel
def update_entry(
    q: np.ndarray,
    row: int,
    state: int,
    action: int,
    reward: np.float32,
    next_state: int,
    terminated: bool,
    next_action: int,
    gamma: np.float32,
    lr: np.float32,
) -> tuple[np.float32, np.float32]:
    """``Q(s, a) += lr * (y - Q(s, a))`` in row ``row`` of ``q [rows, S, A]``, bootstrapping on
    ``Q(s', next_action)`` (``next_action < 0``: on ``max Q(s', .)``); returns ``Q(s, a)`` before and the
    TD error. ``Q(s', .)`` is read before the write, so ``s' = s`` bootstraps on the old values."""
    bootstrap = q[row, next_state].max() if next_action < 0 else q[row, next_state, next_action]
    q_sa = q[row, state, action]
    target = reward if terminated else reward + gamma * bootstrap
    td_error = target - q_sa
    q[row, state, action] = q_sa + lr * td_error
    return q_sa, td_error


@kernel
def update_rows(
    q: np.ndarray,
    rows: np.ndarray,
    states: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_states: np.ndarray,
    terminated: np.ndarray,
    next_actions: np.ndarray,
    gamma: np.float32,
    lr: np.float32,
) -> tuple[np.ndarray, np.ndarray]:
    """One update of each of the distinct ``rows`` of ``q [rows, S, A]`` (:func:`update_entry`, with
    ``next_actions[n] < 0`` for Q-learning's max); returns ``Q(s, a)`` before and the TD errors."""
    q_sa = np.empty(len(rows), dtype=np.float32)
    td_error = np.empty(len(rows), dtype=np.float32)
    for n in range(len(rows)):
        q_sa[n], td_error[n] = update_entry(
            q, rows[n], states[n], actions[n], rewards[n], next_states[n], terminated[n], next_actions[n], gamma, lr
        )
    return q_sa, td_error


@kernel
def update_in_order(
    q: np.ndarray,
    row: int,
    states: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_states: np.ndarray,
    terminated: np.ndarray,
    draws: np.ndarray,
    epsilon: float,
    sarsa: bool,
    gamma: np.float32,
    lr: np.float32,
) -> None:
    """N updates of row ``row`` of ``q [rows, S, A]``, one after another, each reading the values the
    ones before wrote; SARSA's ``a'`` is chosen epsilon-greedily at its update from ``draws [N, 3]``."""
    for n in range(len(states)):
        next_action = choose_action(q[row, next_states[n]], epsilon, draws[n]) if sarsa else -1
        update_entry(q, row, states[n], actions[n], rewards[n], next_states[n], terminated[n], next_action, gamma, lr)
