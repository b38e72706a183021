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
"""

from __future__ import annotations

from typing import Any

import numpy as np
from lbforaging.foraging.environment import ForagingEnv
from pettingzoo import ParallelEnv

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
        self.game = ForagingEnv(
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
