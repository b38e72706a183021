"""Team knowledge exchange during training (``transfer.exchange``), once every ``exchange_every`` episodes.

- ``best``: every other agent moves its values ``exchange_tau`` of the way to the agent with the
  highest mean episodic return over the window (a soft copy). A network's weights move (layers kept
  fixed stay as they are); a table's entries move, over every state either table holds;
- ``shared_replay``: each agent learns from its team-mates' transitions of the window. A DQN agent
  receives them into its replay; a table, which has no replay, is updated on each of them once,
  by its own rule (SARSA draws the next action from its own epsilon-greedy policy).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dqn_transfer.agents import Learner, TabularLearner, Transition


def exchange_best(learner: Learner, window_returns: np.ndarray, tau: float) -> int:
    """Soft-copy the best agent into the others; returns the best agent's index.

    ``window_returns [episodes, K]``: each agent's episodic return over the window.
    """
    best = int(np.argmax(window_returns.mean(axis=0)))
    if isinstance(learner, TabularLearner):
        _soft_copy_tables(learner, best, tau)
        return best
    best_weights = learner.get_member_weights(best)
    frozen = {f"layers.{l}.{kind}" for l in learner.frozen_layers for kind in ("weight", "bias")}
    for i in range(learner.num_agents):
        if i != best:
            own = learner.get_member_weights(i)
            learner.set_member_weights(
                i,
                {
                    name: own[name] if name in frozen else (1 - tau) * own[name] + tau * best_weights[name]
                    for name in own
                },
            )
    return best


def _soft_copy_tables(learner: TabularLearner, best: int, tau: float) -> None:
    """Q_i(s) <- (1 - tau) Q_i(s) + tau Q_best(s) for every other agent i, on every state either table holds
    (a state one of them never saw counts at the value it would look up: its fallback's, or 0)."""
    best_table = learner.tables[best]
    for i in range(learner.num_agents):
        if i == best:
            continue
        for key in list(dict.fromkeys([*learner.tables[i], *best_table])):
            obs = np.frombuffer(key, dtype=np.float32)
            learner.tables[i][key] = (
                (1 - tau) * learner.agent_q_values(i, obs) + tau * learner.agent_q_values(best, obs)
            ).astype(np.float32)


def exchange_replay(learner: Learner, transitions: Sequence[Transition], step: int) -> None:
    """Each agent learns from its team-mates' transitions of the window (see the module docstring)."""
    if not transitions:
        return
    window = Transition(*(np.stack(column) for column in zip(*transitions)))  # fields [T, K, ...]
    for giver in range(learner.num_agents):
        taken = window.live[:, giver]  # only the steps where the giver was acting
        experience = [
            column[taken, giver]
            for column in (window.obs, window.actions, window.rewards, window.next_obs, window.terminated)
        ]
        for receiver in range(learner.num_agents):
            if receiver == giver:
                continue
            if isinstance(learner, TabularLearner):
                _update_on(learner, receiver, *experience, step=step)
            else:
                learner.add_experience(receiver, *experience)


def _update_on(
    learner: TabularLearner,
    receiver: int,
    obs: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    next_obs: np.ndarray,
    terminated: np.ndarray,
    step: int,
) -> None:
    """One table update of ``receiver`` per transition, as if it had been its own. Each is marked
    truncated where not terminated: that bootstraps like any non-terminal step, but leaves SARSA's
    cached next action, which belongs to the receiver's own next step, alone."""
    k = learner.num_agents
    live = np.zeros(k, dtype=bool)
    live[receiver] = True  # the receiver's row of each joint transition is the only one read
    for o, a, r, o2, done in zip(obs, actions, rewards, next_obs, terminated):
        learner.update(
            Transition(
                np.repeat(o[None], k, axis=0),
                np.full(k, a),
                np.full(k, r, dtype=np.float32),
                np.repeat(o2[None], k, axis=0),
                np.full(k, done),
                np.full(k, not done),
                live,
            ),
            step,
        )
