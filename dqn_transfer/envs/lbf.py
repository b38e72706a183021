"""Level-Based Foraging (the ``lbforaging`` package) as a PettingZoo ParallelEnv with named observation
segments: the factory of ``env=lbf`` (docs/your_own_environment.md).

lbforaging's ``ForagingEnv`` is a Gymnasium env with tuple spaces (one entry per player); this adapter
gives it PettingZoo's parallel API (agents ``player_0`` ..) and two changes of meaning:

* the episode's time limit is a **truncation** (lbforaging reports it as ``done``), so learners
  bootstrap past it;
* a reset is a function of its seed alone: lbforaging's own places the new players away from the cells
  the last episode's players ended on, so the same seed gave another start after another episode (and
  a mid-episode checkpoint's replay could miss); the adapter clears those positions first;
* every player's observation is declared as segments, in lbforaging's order: ``food_0`` ..
  ``food_{F-1}`` (row, col, level of each food seen, ``(-1, -1, 0)`` when not seen), ``self`` (row,
  col, level) and ``player_1`` .. ``player_{P-1}`` (the other players seen). Transfer maps segments by
  name, so a source trained with fewer food items or players starts a larger task with its segments'
  weights and the new entries at zero weight: it computes the source's Q-values on every state the
  source could see (docs/transfer.md).

Two of lbforaging's methods run again here, faster, with the same results (``tests/test_lbf.py`` plays
them side by side with the originals): the observation vectors, written by a compiled kernel instead of
through named tuples and a space check of every vector, and each player's valid actions, read from the
field as a list (under a profiler the two took 37% of an LBF run's time).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from lbforaging.foraging.environment import Action, ForagingEnv
from pettingzoo import ParallelEnv

from dqn_transfer.compiled import kernel

ENTRY = 3  # (row, col, level) of one food item or player


def lbf_segments(food: int, players: int) -> list[tuple[str, int]]:
    """The named segments of an LBF observation with ``food`` items and ``players`` players.

    :param food: the most food items on the field.
    :param players: the players.
    """
    return (
        [(f"food_{i}", ENTRY) for i in range(food)]
        + [("self", ENTRY)]
        + [(f"player_{i}", ENTRY) for i in range(1, players)]
    )


@kernel
def write_observations(
    field: np.ndarray, positions: np.ndarray, levels: np.ndarray, sight: int, observe_levels: bool, out: np.ndarray
) -> None:
    """Every player's observation vector into ``out [players, width]``, as lbforaging's ``_make_gym_obs``
    writes it: the food in the player's window (the field within ``sight`` of it, clipped at the edges) in
    row-major order as (row, col, level) from the window's corner, ``(-1, -1, 0)`` for the rest; then the
    player itself and the others it sees, in their order, with positions from the same corner. lbforaging
    sees a player when both of its coordinates from that corner are within ``0..2 * sight``, which past the
    field's edge reaches beyond the food window: kept as it is.
    """
    rows, cols = field.shape
    players = positions.shape[0]
    entry = ENTRY if observe_levels else ENTRY - 1  # a player's (row, col[, level])
    food = (out.shape[1] - players * entry) // ENTRY
    for p in range(players):
        obs = out[p]
        row, col = positions[p, 0], positions[p, 1]
        top, left = max(row - sight, 0), max(col - sight, 0)
        for i in range(food):
            obs[3 * i], obs[3 * i + 1], obs[3 * i + 2] = -1.0, -1.0, 0.0
        seen = 0
        for y in range(top, min(row + sight + 1, rows)):
            for x in range(left, min(col + sight + 1, cols)):
                if field[y, x] != 0:
                    obs[3 * seen], obs[3 * seen + 1], obs[3 * seen + 2] = y - top, x - left, field[y, x]
                    seen += 1
        start = 3 * food
        for i in range(players):
            obs[start + entry * i], obs[start + entry * i + 1] = -1.0, -1.0
            if observe_levels:
                obs[start + entry * i + 2] = 0.0
        slot = 0
        for order in range(players):  # the player itself first, then the others in their order
            other = p if order == 0 else order - 1 + (order - 1 >= p)
            y, x = positions[other, 0] - top, positions[other, 1] - left
            if min(y, x) >= 0 and max(y, x) <= 2 * sight:
                obs[start + entry * slot], obs[start + entry * slot + 1] = y, x
                if observe_levels:
                    obs[start + entry * slot + 2] = levels[other]
                slot += 1


class FastForagingEnv(ForagingEnv):
    """lbforaging's ``ForagingEnv`` with its vector observations and valid actions computed faster, to the
    same values (its grid observations are lbforaging's own)."""

    def _make_gym_obs(self) -> tuple[np.ndarray, ...]:
        if self._grid_observation:
            return super()._make_gym_obs()
        positions = np.array([player.position for player in self.players], dtype=np.int64)
        levels = np.array([player.level for player in self.players], dtype=np.int64)
        out = np.empty((len(self.players), *self.observation_space[0].shape), dtype=np.float32)
        write_observations(self.field, positions, levels, self.sight, self._observe_agent_levels, out)
        return tuple(out)

    def _gen_valid_moves(self) -> None:
        field = self.field.tolist()
        last_row, last_col = len(field) - 1, len(field[0]) - 1
        self._valid_actions = {}
        for player in self.players:
            row, col = player.position
            valid = [Action.NONE]
            if row > 0 and field[row - 1][col] == 0:
                valid.append(Action.NORTH)
            if row < last_row and field[row + 1][col] == 0:
                valid.append(Action.SOUTH)
            if col > 0 and field[row][col - 1] == 0:
                valid.append(Action.WEST)
            if col < last_col and field[row][col + 1] == 0:
                valid.append(Action.EAST)
            # lbforaging's adjacent_food: the four neighbours clamped to the field (so at an edge the
            # player's own cell, which holds no food)
            adjacent = (
                field[max(row - 1, 0)][col]
                + field[min(row + 1, last_row)][col]
                + field[row][max(col - 1, 0)]
                + field[row][min(col + 1, last_col)]
            )
            if adjacent > 0:
                valid.append(Action.LOAD)
            self._valid_actions[player] = valid


class LevelBasedForaging(ParallelEnv):
    """lbforaging's ``ForagingEnv`` behind PettingZoo's parallel API.

    :param size: the field's side.
    :param players: the players (agents).
    :param food: the most food items on the field.
    :param max_player_level: players' levels are drawn in 1..this each episode.
    :param min_food_level: the lowest food level.
    :param max_food_level: the highest food level; None: the sum of the three lowest players' levels.
    :param force_coop: every food needs all players to load it together (cooperative food).
    :param sight: how far a player sees; None: the whole field.
    :param max_steps: the time limit (a truncation).
    :param penalty: the reward of a failed load.
    :param render_mode: None or rgb_array.
    """

    metadata = {"name": "lbf_v0", "render_modes": ["rgb_array"]}

    def __init__(
        self,
        size: int = 8,
        players: int = 2,
        food: int = 2,
        max_player_level: int = 2,
        min_food_level: int = 1,
        max_food_level: int | None = None,
        force_coop: bool = False,
        sight: int | None = None,
        max_steps: int = 50,
        penalty: float = 0.0,
        render_mode: str | None = None,
    ) -> None:
        self.game = FastForagingEnv(
            players=players,
            min_player_level=1,
            max_player_level=max_player_level,
            min_food_level=min_food_level,
            max_food_level=max_food_level,
            field_size=(size, size),
            max_num_food=food,
            sight=size if sight is None else sight,
            max_episode_steps=max_steps,
            force_coop=force_coop,
            penalty=penalty,
            render_mode=render_mode,
        )
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.possible_agents = [f"player_{i}" for i in range(players)]
        self.agents: list[str] = []
        self.observation_segments = lbf_segments(food, players)

    def observation_space(self, agent: str) -> Any:
        return self.game.observation_space[self.possible_agents.index(agent)]

    def action_space(self, agent: str) -> Any:
        return self.game.action_space[self.possible_agents.index(agent)]

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        for player in self.game.players:
            player.position = None  # lbforaging places players away from the last episode's: forget them
        observations, _ = self.game.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        return dict(zip(self.agents, observations)), {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        joint = [int(actions.get(agent, 0)) for agent in self.possible_agents]  # 0: lbforaging's NONE
        observations, rewards, done, _, _ = self.game.step(joint)
        food_left = bool(np.any(self.game.field))
        time_up = done and food_left  # lbforaging ends the episode at the time limit with food left
        agents = self.agents
        self.agents = [] if done else list(self.possible_agents)
        return (
            dict(zip(agents, observations)),
            {agent: float(r) for agent, r in zip(agents, rewards)},
            {agent: done and not time_up for agent in agents},
            {agent: time_up for agent in agents},
            {agent: {} for agent in agents},
        )

    def render(self) -> Any:
        return self.game.render(mode="rgb_array") if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.game.close()


def parallel_env(**kwargs: Any) -> LevelBasedForaging:
    """``env=lbf``'s factory: a :class:`LevelBasedForaging` for ``kwargs``."""
    return LevelBasedForaging(**kwargs)
