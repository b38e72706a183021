"""The R games of a run's replicas as one :class:`~dqn_transfer.envs.batch.GameBatch`: treasure hunts
that share their size, chest count and rules are one :class:`~dqn_transfer.envs.game.TreasureHunts`
(the compiled rules over all of them); any other games (another game, or maps that cannot share a batch)
are stepped one after another (:class:`LoopedGames`). A replica's chest ties are drawn from its own
generator in the same order either way (``tests/test_game_batch.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from dqn_transfer.envs import Game
from dqn_transfer.envs.batch import BatchStep, GameBatch
from dqn_transfer.envs.game import TreasureHunts, fit_one_batch
from dqn_transfer.envs.pettingzoo_game import PettingZooGame


class LoopedGames(GameBatch):
    """Any games with the one-game core's interface, stepped one after another."""

    def __init__(self, games: Sequence[Game], rngs: Sequence[np.random.Generator]) -> None:
        """
        :param games: one game per replica, each at the start of (or inside) the episode to continue
        :param rngs: each replica's generator, given to the game at every reset
        """
        self.games, self.rngs = list(games), list(rngs)
        self.num_replicas, self.num_agents = len(self.games), self.games[0].num_agents
        self._obs = np.stack([game.state_dict()["obs"] for game in self.games]).astype(np.float32)
        self._live = np.stack([game.live for game in self.games])

    @property
    def obs(self) -> np.ndarray:
        return self._obs

    @property
    def live(self) -> np.ndarray:
        return self._live

    def step(self, actions: np.ndarray) -> BatchStep:
        outcomes = [game.step(row) for game, row in zip(self.games, actions)]
        self._obs = np.stack([o.obs for o in outcomes])
        self._live = np.stack([o.live for o in outcomes])
        return BatchStep(
            next_obs=self._obs,
            rewards=np.stack([o.rewards for o in outcomes]),
            terminated=np.stack([o.terminated for o in outcomes]),
            truncated=np.stack([o.truncated for o in outcomes]),
            trap=np.stack([o.trap for o in outcomes]),
            bounced=np.stack([o.bounced for o in outcomes]),
            treasures_collected=np.array([o.treasures_collected for o in outcomes], dtype=np.int64),
            episode_treasures=np.array([game.treasures_collected for game in self.games], dtype=np.int64),
            episode_end=np.asarray(~self._live.any(axis=1)),
        )

    def reset(self, which: np.ndarray) -> None:
        for r in self._to_reset(which):
            self._obs[r] = self.games[r].reset(self.rngs[r])
            self._live[r] = self.games[r].live

    def _to_reset(self, which: np.ndarray) -> list[int]:
        """The replicas of the mask ``which``; if any, the observation arrays are copied first, so that the arrays
        a step returned keep what it saw."""
        replicas = np.flatnonzero(which).tolist()
        if replicas:
            self._obs, self._live = self._obs.copy(), self._live.copy()
        return replicas

    def state_dict(self, replica: int) -> dict[str, Any]:
        return self.games[replica].state_dict()

    def load_state_dict(self, replica: int, state: Mapping[str, Any]) -> None:
        obs = self.games[replica].load_state_dict(state, self.rngs[replica])
        self._obs, self._live = self._obs.copy(), self._live.copy()
        self._obs[replica], self._live[replica] = obs, self.games[replica].live


def env_batch(games: Sequence[Game], rngs: Sequence[np.random.Generator]) -> GameBatch | None:
    """The games as the batch their env makes of them, or None: PettingZoo games whose ParallelEnv class has a
    static ``batch_games(games, rngs)`` (giving a batch, or None where it cannot take these games), as LBF's
    ``LevelBasedForaging.batch_games``."""
    pettingzoo = [game for game in games if isinstance(game, PettingZooGame)]
    if len(pettingzoo) < len(games):
        return None
    batch_games = getattr(type(pettingzoo[0].env), "batch_games", None)
    return None if batch_games is None else batch_games(pettingzoo, rngs)


def game_batch(games: Sequence[Game], rngs: Sequence[np.random.Generator]) -> GameBatch:
    """The replicas' games as one batch, each continuing its game's episode: one :class:`TreasureHunts`
    for treasure hunts that fit one batch, their env's own batch where it has one (:func:`env_batch`), else a
    loop over the games."""
    if fit_one_batch(games):
        return TreasureHunts.of_games(games, rngs)
    return env_batch(games, rngs) or LoopedGames(games, rngs)
