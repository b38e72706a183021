"""Gymnasium face: ``TreasureHunt-v0``, the single-agent MDP of a treasure-hunt map.

The source task of transfer: agent 0 alone on the same map (its start, every chest and trap),
observing ``position`` [+ ``view``]; terminated on a chest or a trap, truncated at ``max_steps``.
It accepts the same keyword arguments as the multi-agent faces so one env config serves both;
``mode`` and ``reward_mode`` are validated but make no difference to a lone agent.

With no map given (no ``map_seed``, ``layout`` or ``layout_file``) the map is the generated one of
map seed :data:`DEFAULT_MAP_SEED`, the trainer's ``env=simple`` map: map seed 0 starts the agent
beside its chest, a one-step task on which any library "solves" ``gymnasium.make("TreasureHunt-v0")``
at step 0.
"""

from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium import spaces

from dqn_transfer.envs.game import make_game

# The map seed of TreasureHunt-v0 when no map is given (conf/env/simple.yaml's): the nearest chest is
# several moves from the start, so a one-step policy cannot reach it.
DEFAULT_MAP_SEED = 6


class TreasureHuntEnv(gymnasium.Env):
    metadata = {"render_modes": ["ansi", "rgb_array", "human"], "render_fps": 4}

    def __init__(self, render_mode: str | None = None, **env_kwargs) -> None:
        if all(env_kwargs.get(key) is None for key in ("map_seed", "layout", "layout_file")):
            env_kwargs["map_seed"] = DEFAULT_MAP_SEED
        self.game = make_game(render_mode=render_mode, **env_kwargs).single_agent_game()
        self.render_mode = render_mode
        self.observation_space = spaces.Box(0.0, 1.0, shape=(self.game.obs_dim,), dtype=np.float32)
        self.action_space = spaces.Discrete(self.game.num_actions)
        self._action = np.zeros(1, dtype=np.int64)

    def obs_layout(self) -> list[tuple[str, int]]:
        return self.game.obs_layout()

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        obs = self.game.reset(self.np_random)[0]
        if self.render_mode == "human":
            self.render()
        return obs, {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        self._action[0] = action
        outcome = self.game.step(self._action)
        if self.render_mode == "human":
            self.render()
        return (
            outcome.obs[0],
            float(outcome.rewards[0]),
            bool(outcome.terminated[0]),
            bool(outcome.truncated[0]),
            {"treasures_collected": outcome.treasures_collected, "trap": bool(outcome.trap[0])},
        )

    def render(self) -> str | np.ndarray | None:
        return self.game.render(self.render_mode)
