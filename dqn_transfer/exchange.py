"""Team knowledge exchange during training (``transfer.exchange``), once every ``exchange_every`` episodes.

- ``best``: every other agent moves its weights ``exchange_tau`` of the way to the agent with the
  highest mean episodic return over the window (a soft copy; layers kept fixed stay as they are);
- ``shared_replay``: each agent receives its team-mates' transitions of the window into its replay.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dqn_transfer.agents import BatchedDQN, Transition


def exchange_best(learner: BatchedDQN, window_returns: np.ndarray, tau: float) -> int:
    """Soft-copy the best agent into the others; returns the best agent's index.

    ``window_returns [episodes, K]``: each agent's episodic return over the window.
    """
    best = int(np.argmax(window_returns.mean(axis=0)))
    best_weights = learner.get_member_weights(best)
    frozen = {f"layers.{l}.{kind}" for l in learner.frozen_layers for kind in ("weight", "bias")}
    for i in range(learner.num_agents):
        if i != best:
            own = learner.get_member_weights(i)
            learner.set_member_weights(i, {name: own[name] if name in frozen else
                                           (1 - tau) * own[name] + tau * best_weights[name] for name in own})
    return best


def exchange_replay(learner: BatchedDQN, transitions: Sequence[Transition]) -> None:
    """Each agent adds its team-mates' transitions of the window to its own replay row."""
    if not transitions:
        return
    window = Transition(*(np.stack(column) for column in zip(*transitions)))  # fields [T, K, ...]
    for giver in range(learner.num_agents):
        taken = window.live[:, giver]  # only the steps where the giver was acting
        experience = [column[taken, giver] for column in
                      (window.obs, window.actions, window.rewards, window.next_obs, window.terminated)]
        for receiver in range(learner.num_agents):
            if receiver != giver:
                learner.add_experience(receiver, *experience)
