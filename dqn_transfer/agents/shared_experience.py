"""Shared experience for the DQN learners (``transfer.exchange=experience``).

SEAC's idea (Christianos, Schäfer & Albrecht 2020, "Shared Experience Actor-Critic for Multi-Agent
Reinforcement Learning"; SEQL is its Q-learning variant) applied to DQN: every gradient step of agent i
is on a batch drawn from **every** team-mate's replay, its own included, and the team-mates' samples
weigh ``experience_lambda`` times an own sample in its loss. Replicas stay apart: replica r's agents
draw only from replica r's rows.

**Equal shares.** Agent i's batch of B holds ``B // K`` samples from each team-mate's replay and the
rest, ``B - (K - 1) * (B // K)``, from its own (so own samples are never fewer; with B < K no team-mate
gets any). Own samples come first in the batch, then each team-mate's in index order
(:func:`batch_sources`).

**The loss** is the weighted mean over the batch, ``sum_b w_b huber(e_b) / sum_b w_b`` with ``w = 1``
for own samples and ``lambda`` for team-mates' (:func:`~dqn_transfer.agents.dqn_update.td_losses`):
with equal shares that is SEAC's ``L_own + lambda * sum_j L_j`` divided by ``1 + lambda * (K - 1)``, so
``lambda = 1`` is the ordinary DQN loss of the mixed batch and ``lambda = 0`` exactly the loss (and
gradient) of the own samples alone. The constant factor matters only through the gradient-norm clip
(Adam does not see a constant scale). A sample from a row with no data yet weighs 0.

**No correction.** SEAC weights a team-mate's sample by the importance ratio ``pi_i(a|o) / pi_j(a|o)``
because its actor-critic loss is on-policy. The Q-learning target ``r + gamma max_a' Q(s', a')`` (or
Double DQN's) does not depend on the policy that chose ``a``: a team-mate's transition is off-policy
data like any old transition in the agent's own replay, so none is needed, as in SEQL.

Compared with ``shared_replay`` (team-mates' transitions copied into each agent's replay once per
exchange window): that changes what the replay holds (team-mates' transitions then displace the agent's
own from its ring, in proportion to how much the team plays) and leaves the loss alone; this leaves the
replays alone and fixes each batch's mix and the weight of the team-mates' part.
"""

from __future__ import annotations

import numpy as np


def batch_sources(num_agents: int, batch_size: int) -> np.ndarray:
    """``int64 [K, B]``: the team-mate whose replay each sample of agent k's batch comes from (own
    samples first, then each team-mate's ``B // K`` in index order; see the module docstring)."""
    share = batch_size // num_agents
    own = batch_size - (num_agents - 1) * share
    sources = np.empty((num_agents, batch_size), dtype=np.int64)
    for k in range(num_agents):
        mates = [j for j in range(num_agents) if j != k]
        sources[k] = np.concatenate([np.full(own, k), np.repeat(mates, share)])
    return sources


class SharedExperience:
    """Where each sample of every agent's batch comes from, and its weight in the agent's loss, for R
    replicas of K agents (rows ``r * K + k``).

    :param num_replicas: R
    :param num_agents: K
    :param batch_size: B, each agent's batch
    :param experience_lambda: a team-mate's sample's weight relative to an own one (``transfer.experience_lambda``)
    """

    def __init__(self, num_replicas: int, num_agents: int, batch_size: int, experience_lambda: float) -> None:
        local = batch_sources(num_agents, batch_size)
        replica_start = np.repeat(np.arange(num_replicas) * num_agents, num_agents)[:, None]
        self.sources = np.tile(local, (num_replicas, 1)) + replica_start  # [R * K, B]: the replay row of each sample
        own = self.sources == np.arange(num_replicas * num_agents)[:, None]
        self.weights = np.where(own, 1.0, experience_lambda).astype(np.float32)  # before normalisation
        self.experience_lambda = experience_lambda
        self._cache: tuple[bytes, np.ndarray] | None = None

    def sample_weights(self, filled: np.ndarray) -> np.ndarray:
        """``float32 [rows, B]``: each sample's weight in its row's loss, each row summing to 1 (all 0 for
        a row whose samples all come from empty rows), given which replay rows hold data, ``filled
        [rows]``. Cached while the same rows hold data (the same array is returned)."""
        key = filled.tobytes()
        if self._cache is None or self._cache[0] != key:
            weights = self.weights * filled[self.sources]
            totals = weights.sum(axis=1, keepdims=True)
            self._cache = (key, (weights / np.where(totals > 0, totals, 1)).astype(np.float32))
        return self._cache[1]
