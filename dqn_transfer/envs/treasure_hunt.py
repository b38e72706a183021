"""PettingZoo face of the treasure hunt: ``parallel_env(**kw)`` and ``env(**kw)`` (AEC).

Follows the PettingZoo custom-environment API: agents ``agent_0``..``agent_{K-1}``, cached spaces,
``reset(seed, options) -> (observations, infos)``, ``step(actions)`` returning five dicts keyed by
the agents live before the step, and finished agents removed from ``agents``. With
``render_mode="human"`` every reset and step prints the text frame. The game itself is
:class:`~dqn_transfer.envs.game.TreasureHuntGame` (``env.game``), which the trainer drives directly.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from dqn_transfer.envs.game import make_game


class TreasureHuntParallelEnv(ParallelEnv):
    """All live agents act at once. Keyword arguments: the keys of :class:`~dqn_transfer.envs.settings.EnvConfig`."""

    metadata = {
        "name": "treasure_hunt_v0",
        "render_modes": ["ansi", "rgb_array", "human"],
        "render_fps": 4,
        "is_parallelizable": True,
    }

    def __init__(self, render_mode: str | None = None, **env_kwargs) -> None:
        self.game = make_game(render_mode=render_mode, **env_kwargs)
        self.render_mode = render_mode
        self.possible_agents = [f"agent_{i}" for i in range(self.game.num_agents)]
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        dim = self.game.obs_dim
        self.observation_spaces = {
            name: spaces.Box(0.0, 1.0, shape=(dim,), dtype=np.float32) for name in self.possible_agents
        }
        self.action_spaces = {name: spaces.Discrete(self.game.num_actions) for name in self.possible_agents}
        self._actions = np.zeros(self.game.num_agents, dtype=np.int64)
        self._rng = np.random.default_rng()

    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        return self.action_spaces[agent]

    def obs_layout(self, agent: str | None = None) -> list[tuple[str, int]]:
        """Named observation segments (the same for every agent)."""
        return self.game.obs_layout()

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        obs = self.game.reset(self._rng)
        self.agents = self.possible_agents[:]
        if self.render_mode == "human":
            self.render()
        return {name: obs[i] for i, name in enumerate(self.agents)}, {a: {} for a in self.agents}

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        acting = self.agents
        for name in acting:
            if name not in actions:
                raise ValueError(f"no action for live agent {name}")
            self._actions[self._index[name]] = actions[name]
        obs, rewards, terminated, truncated, *_ = self.game.step(self._actions)
        rows = [self._index[name] for name in acting]
        rew, term, trunc = rewards.tolist(), terminated.tolist(), truncated.tolist()
        self.agents = [name for name, i in zip(acting, rows) if not (term[i] or trunc[i])]
        if self.render_mode == "human":
            self.render()
        return (
            {name: obs[i] for name, i in zip(acting, rows)},
            {name: rew[i] for name, i in zip(acting, rows)},
            {name: term[i] for name, i in zip(acting, rows)},
            {name: trunc[i] for name, i in zip(acting, rows)},
            {name: {} for name in acting},
        )

    def render(self) -> str | np.ndarray | None:
        return self.game.render(self.render_mode)

    def close(self) -> None:
        """Nothing to release: rendering draws into arrays, no window."""


def parallel_env(**kwargs) -> TreasureHuntParallelEnv:
    return TreasureHuntParallelEnv(**kwargs)


def env(**kwargs) -> AECEnv:
    """AEC version (agents act in turn, the joint move happens after the last one)."""
    aec = parallel_to_aec(parallel_env(**kwargs))
    return wrappers.OrderEnforcingWrapper(wrappers.AssertOutOfBoundsWrapper(aec))
