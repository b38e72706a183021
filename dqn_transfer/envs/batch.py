"""What the training loop and the evaluations step: R games with K agents each, arrays in, arrays out.

The treasure hunt's R games are one :class:`~dqn_transfer.envs.game.TreasureHunts` (its rules compiled
over the replicas); any other game's replicas go one after another
(:class:`~dqn_transfer.envs.game_batch.LoopedGames`). A batch never resets on its own: the loop logs a
replica's finished episode first, then calls :meth:`GameBatch.reset` for it. A replica's episode in
progress is saved and restored in the one-game format (``TreasureHuntGame.state_dict``), so checkpoints
are the same files however the games are stepped.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np


class BatchStep(NamedTuple):
    """What one joint step of R games did (``K`` agents each; a non-live agent's row is zero / False).

    ``next_obs [R, K, obs_dim] float32``: the observations right after the step (before any reset).
    ``rewards [R, K] float32``; ``terminated``, ``truncated``, ``trap`` ``[R, K] bool``; ``bounced [R, K]
    bool``: moved into an obstacle, and so back to its own start (never, in a game without obstacles);
    ``treasures_collected [R] int64``: chests emptied by this step; ``episode_treasures [R] int64``:
    chests emptied so far in the episode, this step included; ``episode_end [R] bool``: no agent of the
    replica is live any more (reset it before the next step).
    """

    next_obs: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    trap: np.ndarray
    bounced: np.ndarray
    treasures_collected: np.ndarray
    episode_treasures: np.ndarray
    episode_end: np.ndarray


class GameBatch(ABC):
    """R games with ``num_agents`` agents each, stepped together; replica r draws its chest ties from
    ``rngs[r]`` (the generator its resets were given in the one-game core)."""

    num_replicas: int
    num_agents: int

    # ------------------------------------------------------------------ what a step reads
    @property
    @abstractmethod
    def obs(self) -> np.ndarray:
        """``[R, K, obs_dim] float32``: the observations to act on (do not modify)."""

    @property
    @abstractmethod
    def live(self) -> np.ndarray:
        """``[R, K] bool``: who acts next (do not modify)."""

    # ------------------------------------------------------------------ dynamics
    @abstractmethod
    def step(self, actions: np.ndarray) -> BatchStep:
        """One joint step of every replica with ``actions [R, K]`` (non-live agents' are ignored)."""

    @abstractmethod
    def reset(self, which: np.ndarray) -> None:
        """Start a new episode in the replicas of the mask ``which [R] bool``."""

    # ------------------------------------------------------------------ one replica's episode
    @abstractmethod
    def state_dict(self, replica: int) -> dict[str, Any]:
        """Replica ``replica``'s episode in progress, in the one-game core's format."""

    @abstractmethod
    def load_state_dict(self, replica: int, state: Mapping[str, Any]) -> None:
        """Continue a :meth:`state_dict`'s episode in replica ``replica`` (``ValueError`` if it does not
        fit the replica's game)."""
