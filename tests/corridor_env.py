"""A PettingZoo ParallelEnv the project does not ship, for the tests of env=pettingzoo: two agents walk a
corridor of ``length`` cells to its right end.

It exercises what an outside env may do: the agents' spaces differ (``walker`` observes its cell as
``Discrete(length)`` and has 3 actions: left, stay, right; ``runner`` observes ``Box(2)``: its cell scaled
to [0, 1] and a noise draw, and has 2 actions: left, right), a move slips the other way with probability
``slip`` (drawn from the env's seeded generator), an agent that reaches the end gets +1 and leaves the
episode while the other plays on, every other step costs -0.1, and ``max_steps`` truncates. The other
factories here return what the adapter must refuse.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec


class Corridor(ParallelEnv):
    metadata = {"name": "corridor_v0"}

    def __init__(self, length: int = 5, max_steps: int = 12, slip: float = 0.2) -> None:
        self.length, self.max_steps, self.slip = length, max_steps, slip
        self.possible_agents = ["walker", "runner"]
        self.agents: list[str] = []
        self._spaces = {
            "walker": (spaces.Discrete(length), spaces.Discrete(3)),
            "runner": (spaces.Box(0.0, 1.0, shape=(2,), dtype=np.float32), spaces.Discrete(2)),
        }
        self.np_random = np.random.default_rng()

    def observation_space(self, agent):
        return self._spaces[agent][0]

    def action_space(self, agent):
        return self._spaces[agent][1]

    def _observe(self, agent):
        cell = self.cells[agent]
        if agent == "walker":
            return cell
        return np.array([cell / (self.length - 1), self.np_random.random()], dtype=np.float32)

    def reset(self, seed=None, options=None):
        if seed is not None:
            self.np_random = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.cells = {agent: 0 for agent in self.agents}
        self.t = 0
        return {agent: self._observe(agent) for agent in self.agents}, {agent: {} for agent in self.agents}

    def step(self, actions):
        self.t += 1
        moves = {"walker": (-1, 0, 1), "runner": (-1, 1)}
        rewards, terminations, truncations = {}, {}, {}
        for agent in self.agents:
            move = moves[agent][actions[agent]]
            if self.np_random.random() < self.slip:
                move = -move
            self.cells[agent] = int(np.clip(self.cells[agent] + move, 0, self.length - 1))
            terminations[agent] = self.cells[agent] == self.length - 1
            rewards[agent] = 1.0 if terminations[agent] else -0.1
            truncations[agent] = self.t >= self.max_steps and not terminations[agent]
        observations = {agent: self._observe(agent) for agent in self.agents}
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, {agent: {} for agent in observations}


def parallel_env(**kwargs) -> Corridor:
    return Corridor(**kwargs)


class _ChangedSpace(Corridor):
    def __init__(self, space) -> None:
        super().__init__()
        self._changed = space

    def observation_space(self, agent):
        return self._changed if agent == "runner" else super().observation_space(agent)


def dict_observations() -> Corridor:
    return _ChangedSpace(spaces.Dict({"cell": spaces.Discrete(5)}))


def image_observations() -> Corridor:
    return _ChangedSpace(spaces.Box(0, 255, shape=(84, 84, 3), dtype=np.uint8))


class _ContinuousRunner(Corridor):
    def action_space(self, agent):
        return spaces.Box(-1.0, 1.0, shape=(1,)) if agent == "runner" else super().action_space(agent)


def continuous_actions() -> Corridor:
    return _ContinuousRunner()


def not_an_env() -> str:
    return "corridor"


class _Unseeded(Corridor):
    def reset(self, seed=None, options=None):
        return super().reset(seed=None, options=options)  # ignores the seed: a replay cannot repeat it


def unseeded() -> Corridor:
    return _Unseeded()


class _TurnBased(Corridor):
    metadata = {"name": "corridor_turns_v0"}


def turn_based() -> AECEnv:
    """An AEC env whose agents take turns, each seeing the move before (not declared parallelizable)."""
    env = parallel_to_aec(_TurnBased())
    env.metadata["is_parallelizable"] = False
    return env
