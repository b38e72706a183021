"""What every learner offers the trainer, and the pieces all learners share.

A learner drives the K agents of a team at once: observations come in as ``float32 [K, D]``,
actions go out as ``int64 [K]``. It sees observation vectors and their segment layout, never the game.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol

import numpy as np

from dqn_transfer.enums import Algorithm

ObsLayout = Sequence[tuple[str, int]]


class Transition(NamedTuple):
    """One joint env step of the K agents, each field ``[K, ...]``; ``live`` marks who acted in it."""

    obs: np.ndarray  # float32 [K, D]
    actions: np.ndarray  # int64 [K]
    rewards: np.ndarray  # float32 [K]
    next_obs: np.ndarray  # float32 [K, D]
    terminated: np.ndarray  # bool [K]: a chest or a trap ended the agent (no bootstrap)
    truncated: np.ndarray  # bool [K]: the time limit ended the episode (the agent still had a future)
    live: np.ndarray  # bool [K]


class UpdateStats(NamedTuple):
    """Per-agent statistics of one ``update``, nan for the agents it did not train."""

    td_loss: np.ndarray  # [K] Huber loss of the TD error
    q_mean: np.ndarray  # [K] mean Q(s, a) of the transitions trained on


class Learner(Protocol):
    """The interface the trainer, checkpoints and transfer rely on (see ``dqn_transfer.agents``)."""

    algorithm: str
    num_agents: int
    obs_layout: list[tuple[str, int]]
    num_actions: int

    def act(
        self,
        obs: np.ndarray,
        live: np.ndarray,
        epsilon: float | np.ndarray,
        greedy: bool = False,
        ties: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Epsilon-greedy actions ``[K]``; when ``greedy``, the best actions, consuming none of the
        learner's random numbers: a tie between equal values (a table's unvisited states) goes to a best
        action drawn from ``ties``, or to the first one without it. Networks take the first best action
        (float outputs practically never tie)."""
        ...

    def update(self, transition: Transition, step: int) -> UpdateStats:
        """Learn from one joint env step; ``step`` counts env steps including this one (1 for the first)."""
        ...

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Each agent's Q-values of its own observation: ``obs [K, D] -> [K, A]`` (a copy)."""
        ...

    def agent_tensors(self, i: int) -> dict[str, np.ndarray]:
        """Agent ``i``'s values, as stored in ``agent_{i}.safetensors`` (contiguous copies)."""
        ...

    def load_agent_tensors(self, i: int, tensors: dict[str, np.ndarray]) -> None: ...

    def network_meta(self) -> dict[str, Any]:
        """JSON-able shape information written beside the tensors."""
        ...

    def training_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Everything besides ``agent_tensors`` that a resumed run needs to continue bit-identically."""
        ...

    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None: ...


class TeamShape:
    """What every learner records about its team: the algorithm, K agents, the observation's segments
    (``obs_dim`` values in all) and A actions."""

    def __init__(self, algorithm: Algorithm, num_agents: int, obs_layout: ObsLayout, num_actions: int) -> None:
        self.algorithm = algorithm.value
        self.num_agents = num_agents
        self.obs_layout = normalize_layout(obs_layout)
        self.obs_dim = sum(size for _, size in self.obs_layout)
        self.num_actions = num_actions


def normalize_layout(obs_layout: ObsLayout) -> list[tuple[str, int]]:
    """Layouts come back from JSON as lists of lists; use ``(name, size)`` tuples throughout."""
    return [(str(name), int(size)) for name, size in obs_layout]


def epsilon_greedy(
    greedy_actions: np.ndarray, epsilon: float | np.ndarray, num_actions: int, rng: np.random.Generator
) -> np.ndarray:
    """Replace each greedy action by a uniformly random one with probability ``epsilon``.

    Always draws two numbers per agent, so the random stream, and thus every later draw, does not
    depend on the value of epsilon.
    """
    explore = rng.random(greedy_actions.shape) < epsilon
    random_actions = rng.integers(0, num_actions, size=greedy_actions.shape)
    return np.where(explore, random_actions, greedy_actions).astype(np.int64)


def epsilon_greedy_action(greedy_action: int, epsilon: float, num_actions: int, rng: np.random.Generator) -> int:
    """:func:`epsilon_greedy` for one agent: the same two draws, taken as scalars (numpy's scalar and
    size-1 draws consume the same random numbers), at a fraction of the per-call cost."""
    explore = rng.random() < epsilon
    random_action = int(rng.integers(0, num_actions))
    return random_action if explore else greedy_action


def joined(parts: Sequence[np.ndarray]) -> np.ndarray:
    """The replicas' rows as one array; a lone replica's own array as it is (no copy: callers pass
    fresh arrays that nothing else holds)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def check_tensor_shape(name: str, tensor: np.ndarray, shape: Sequence[int]) -> None:
    """Loading a tensor of the wrong shape must fail with the name, not deep inside a copy."""
    if tuple(tensor.shape) != tuple(shape):
        raise ValueError(f"tensor '{name}' has shape {list(tensor.shape)}, expected {list(shape)}")
