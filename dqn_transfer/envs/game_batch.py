"""The R games of a run's replicas as one object the training loop steps: arrays in, arrays out.

:func:`game_batch` picks how: enough treasure hunts of one size (:data:`BATCHED_CORE_MIN_REPLICAS`)
go through the batched core (:mod:`dqn_transfer.envs.batched`, one array program for all of them);
fewer, and any other games (another game, or maps that cannot share a batch), are stepped one after
another (:class:`LoopedGames`). Both give the same numbers: a replica's chest ties are drawn from its
own generator, in the same order (``tests/test_game_batch.py``).

A batch never resets on its own: the loop logs a replica's finished episode first, then calls
:meth:`GameBatch.reset` for it. A replica's episode in progress is saved and restored in the one-game
format (:meth:`~dqn_transfer.envs.game.TreasureHuntGame.state_dict`), so checkpoints are the same
files whichever way the games are stepped.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple, TypeGuard

import numpy as np

from dqn_transfer.envs import Game, batched
from dqn_transfer.envs.game import TreasureHuntGame


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
        replicas = np.flatnonzero(which).tolist()
        if not replicas:
            return
        self._obs, self._live = self._obs.copy(), self._live.copy()
        for r in replicas:
            self._obs[r] = self.games[r].reset(self.rngs[r])
            self._live[r] = self.games[r].live

    def state_dict(self, replica: int) -> dict[str, Any]:
        return self.games[replica].state_dict()

    def load_state_dict(self, replica: int, state: Mapping[str, Any]) -> None:
        obs = self.games[replica].load_state_dict(state, self.rngs[replica])
        self._obs, self._live = self._obs.copy(), self._live.copy()
        self._obs[replica], self._live[replica] = obs, self.games[replica].live


class BatchedTreasureHunts(GameBatch):
    """R treasure hunts of one size through the batched core: one array program per step."""

    def __init__(self, games: Sequence[TreasureHuntGame], rngs: Sequence[np.random.Generator]) -> None:
        """
        :param games: one game per replica (same size, agent and chest counts, rules), each at the
            start of (or inside) the episode to continue; only their maps, rules and episode states are
            read, and they are not stepped
        :param rngs: each replica's generator of chest ties
        """
        first = games[0]
        self.maps = batched.batch_maps([game.map for game in games], **first.settings())
        self.games, self.rngs = list(games), list(rngs)
        self.num_replicas, self.num_agents = len(self.games), first.num_agents
        self.state, _ = batched.reset(self.maps)
        for r, game in enumerate(games):
            self.load_state_dict(r, game.state_dict())

    @property
    def obs(self) -> np.ndarray:
        return self.state.obs

    @property
    def live(self) -> np.ndarray:
        return self.state.live

    def step(self, actions: np.ndarray) -> BatchStep:
        self.state, outcome = batched.step(self.maps, self.state, actions, self.rngs)
        return BatchStep(
            next_obs=outcome.final_obs,
            rewards=outcome.rewards,
            terminated=outcome.terminated,
            truncated=outcome.truncated,
            trap=outcome.trap,
            bounced=outcome.bounced,
            treasures_collected=outcome.treasures_collected,
            episode_treasures=self.state.treasures_collected,
            episode_end=outcome.episode_end,
        )

    def reset(self, which: np.ndarray) -> None:
        self.state = batched.reset_where(self.maps, self.state, which)

    def state_dict(self, replica: int) -> dict[str, Any]:
        s, k = self.state, self.maps.num_treasures
        return {
            "pos": s.pos[replica].tolist(),
            "live": s.live[replica].tolist(),
            "chest_full": s.chest_full[replica].tolist(),
            "belief": s.belief[replica, :, :k].tolist(),
            "assigned": s.assigned[replica].tolist(),
            "obs": s.obs[replica].tolist(),
            "t": int(s.t[replica]),
            "treasures_collected": int(s.treasures_collected[replica]),
        }

    def load_state_dict(self, replica: int, state: Mapping[str, Any]) -> None:
        game = self.games[replica]
        game.load_state_dict(state, self.rngs[replica])  # checks that the state fits this replica's game
        checked = game.state_dict()
        arrays = [array.copy() for array in self.state]
        pos, live, chest_full, belief, assigned, t, collected, episode_return, obs = arrays
        pos[replica], live[replica], chest_full[replica] = checked["pos"], checked["live"], checked["chest_full"]
        belief[replica, :, : self.maps.num_treasures] = checked["belief"]
        assigned[replica], obs[replica] = checked["assigned"], checked["obs"]
        t[replica], collected[replica] = checked["t"], checked["treasures_collected"]
        episode_return[replica] = 0.0  # the loop keeps the episode's sums (the core's are not read)
        self.state = batched.BatchedState(*arrays)


def fits_one_batch(games: Sequence[Game]) -> TypeGuard[Sequence[TreasureHuntGame]]:
    """Whether ``games`` are treasure hunts the batched core can step together (same size, counts and
    rules; their maps may differ)."""
    first = games[0]
    return all(
        type(game) is TreasureHuntGame
        and type(first) is TreasureHuntGame
        and game.settings() == first.settings()
        and (game.size, game.num_treasures) == (first.size, first.num_treasures)
        for game in games
    )


# Below this many replicas the one-game core in a loop is faster (8x8, 4 agents, stepped as the loop
# steps them: the batched core's rate is 0.9x the loop's at 1 replica, 1.6x at 4, 2.0x at 8 and 11.5x at
# 100 in the cooperative mode, 0.6x / 1.2x / 1.6x / 5.5x deliberative; benchmark/game_batches.py,
# 2026-12-02, median of 3). Either gives the same numbers.
BATCHED_CORE_MIN_REPLICAS = 4


def game_batch(games: Sequence[Game], rngs: Sequence[np.random.Generator]) -> GameBatch:
    """The replicas' games as one batch: the batched core for at least :data:`BATCHED_CORE_MIN_REPLICAS`
    treasure hunts that fit one batch, else a loop over the games."""
    if len(games) >= BATCHED_CORE_MIN_REPLICAS and fits_one_batch(games):
        return BatchedTreasureHunts(games, rngs)
    return LoopedGames(games, rngs)
