"""What a learner can do, as capabilities, and the pieces all learners share.

A learner drives the K agents of a team at once: observations come in as ``float32 [K, D]``,
actions go out as ``int64 [K]``. It sees observation vectors and their segment layout, never the game.

Capabilities (abstract base classes; a learner is an instance of those it has):

- :class:`Acting`: exploring actions, each agent's best actions and Q-values;
- :class:`Learning`: learn from one joint env step;
- :class:`Checkpointing`: agent tensors and the training state a resumed run needs;
- :class:`KnowledgeExchange`: soft-copy the team's best agent into the others, learn from a
  team-mate's transitions (``transfer.exchange``);
- :class:`WarmStart`: what a warm start does beyond loading agent tensors: keep layers fixed, start
  an agent's optimizer from a source's moments (the DQN family).

A :class:`Team` acts and checkpoints; a :class:`Learner` is a team that also learns, batched over R
independent replicas (rows ``r * K + k``; R = 1 for a lone learner), and :meth:`Learner.replica`
gives replica r's team, with the learner's capabilities (:mod:`dqn_transfer.agents.replicas`).
Which capabilities a run needs is checked once, when it is planned, against the learner family its
configuration builds (:mod:`dqn_transfer.config.schema`, :mod:`dqn_transfer.exchange`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any, NamedTuple

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


class Experience(NamedTuple):
    """N transitions of one agent (e.g. a team-mate's, for ``shared_replay``), each field ``[N, ...]``."""

    obs: np.ndarray  # float32 [N, D]
    actions: np.ndarray  # int64 [N]
    rewards: np.ndarray  # float32 [N]
    next_obs: np.ndarray  # float32 [N, D]
    terminated: np.ndarray  # bool [N]


class UpdateStats(NamedTuple):
    """Per-agent statistics of one ``update``, nan for the agents it did not train."""

    td_loss: np.ndarray  # [K] Huber loss of the TD error
    q_mean: np.ndarray  # [K] mean Q(s, a) of the transitions trained on


class TeamShape:
    """What every learner records about its team: the algorithm, K agents, the observation's segments
    (``obs_dim`` values in all) and A actions."""

    def __init__(self, algorithm: Algorithm, num_agents: int, obs_layout: ObsLayout, num_actions: int) -> None:
        self.algorithm = algorithm.value
        self.num_agents = num_agents
        self.obs_layout = normalize_layout(obs_layout)
        self.obs_dim = sum(size for _, size in self.obs_layout)
        self.num_actions = num_actions


# ---------------------------------------------------------------------------------- capabilities


class Acting(ABC):
    """Acting: exploring actions, and the best actions and Q-values of each agent."""

    @abstractmethod
    def act(self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray) -> np.ndarray:
        """Epsilon-greedy actions ``[K]`` of the live agents, drawn from the learner's own random
        numbers (``epsilon`` one value, or one per agent); the others' actions are 0."""

    @abstractmethod
    def best_actions(self, obs: np.ndarray) -> np.ndarray:
        """``bool [K, A]``: each agent's actions of the highest value on its own observation, several
        only where values tie exactly (a table's unvisited states); consumes no random numbers."""

    @abstractmethod
    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Each agent's Q-values of its own observation: ``obs [K, D] -> [K, A]`` (a copy)."""

    def best_actions_stacked(self, obs: np.ndarray) -> np.ndarray:
        """:meth:`best_actions` of E observations per agent, ``obs [E, K, D] -> bool [E, K, A]`` (E
        evaluation episodes side by side); a learner may answer them in one pass."""
        return np.stack([self.best_actions(stacked) for stacked in obs])

    def greedy(self, obs: np.ndarray, live: np.ndarray, ties: np.random.Generator | None = None) -> np.ndarray:
        """The live agents' best actions (the others' are 0), consuming none of the learner's random
        numbers: a tie goes to a best action drawn from ``ties`` (an evaluation episode's own generator),
        or to the first one without it."""
        return break_ties(self.best_actions(obs), live, ties)


class Learning(ABC):
    """Learning from the joint env steps of the team."""

    @abstractmethod
    def update(self, transition: Transition, step: int) -> UpdateStats:
        """Learn from one joint env step; ``step`` counts env steps including this one (1 for the first)."""


class Checkpointing(ABC):
    """What a checkpoint holds: each agent's tensors, and the rest a resumed run needs."""

    @abstractmethod
    def agent_tensors(self, i: int) -> dict[str, np.ndarray]:
        """Agent ``i``'s values, as stored in ``agent_{i}.safetensors`` (contiguous copies)."""

    @abstractmethod
    def load_agent_tensors(self, i: int, tensors: dict[str, np.ndarray]) -> None:
        """Replace agent ``i``'s values by ``tensors`` (a checkpoint's, or a warm start's mapped ones)."""

    @abstractmethod
    def network_meta(self) -> dict[str, Any]:
        """JSON-able shape information written beside the tensors."""

    @abstractmethod
    def training_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Everything besides ``agent_tensors`` that a resumed run needs to continue bit-identically."""

    @abstractmethod
    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        """Restore what :meth:`training_state` returned (after the agents' tensors)."""


class KnowledgeExchange(ABC):
    """Knowledge exchange inside a team during training (``transfer.exchange``)."""

    @abstractmethod
    def soft_copy_best(self, best: int, tau: float) -> None:
        """``best``: every other agent moves its values ``tau`` of the way to agent ``best``'s."""

    @abstractmethod
    def learn_from(self, i: int, experience: Experience) -> None:
        """``shared_replay``: agent ``i`` learns from a team-mate's transitions, by its own rule."""


class WarmStart(ABC):
    """A warm start's steps beyond loading each target's tensors (the DQN family's networks)."""

    @abstractmethod
    def freeze(self, layer_indices: Sequence[int]) -> None:
        """Keep these layers fixed from now on (negative indices count from the output)."""

    @abstractmethod
    def load_optimizer_state(self, i: int, moments: dict[str, dict[str, np.ndarray]], step: int) -> None:
        """Start agent ``i``'s optimizer from a source's moments (``moments[tensor]['exp_avg' | 'exp_avg_sq']``)."""


class ExperienceSharing(ABC):
    """Shared experience (``transfer.exchange=experience``): every gradient step of an agent also on its
    team-mates' replay samples (the DQN family; :mod:`dqn_transfer.agents.shared_experience`)."""

    @abstractmethod
    def share_experience(self, experience_lambda: float) -> None:
        """From now on, draw each agent's batches from all its team-mates' replays, their samples weighing
        ``experience_lambda`` times its own in its loss."""


class Team(TeamShape, Acting, Checkpointing):
    """K agents that act and checkpoint: what evaluation, checkpoints and transfer use. The agent
    indices of every method are 0..K-1."""


class Learner(Team, Learning):
    """A team that learns, batched over ``num_replicas`` independent replicas: every array is
    ``[R * K, ...]``, replica-major (row ``r * K + k``), and an agent index is a row. With R = 1 it
    is one team; :meth:`replica` is replica r's team, with the learner's capabilities."""

    num_replicas: int
    num_rows: int

    @abstractmethod
    def replica(self, r: int) -> Team:
        """Replica r's team of K agents (reads and writes this learner's own values)."""


def break_ties(best: np.ndarray, live: np.ndarray, ties: np.random.Generator | None) -> np.ndarray:
    """Actions ``[K]`` from best-action masks ``bool [K, A]``: the live agents' first best action, or,
    with ``ties``, a best action drawn from it where several tie (one draw per such agent, in order);
    0 for the others."""
    actions = np.where(live, best.argmax(axis=1), 0).astype(np.int64)
    if ties is not None:
        for i in np.flatnonzero(live & (best.sum(axis=1) > 1)):
            choices = np.flatnonzero(best[i])
            actions[i] = choices[int(ties.integers(len(choices)))]
    return actions


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


def joined(parts: Sequence[np.ndarray]) -> np.ndarray:
    """The replicas' rows as one array; a lone replica's own array as it is (no copy: callers pass
    fresh arrays that nothing else holds)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def check_tensor_shape(name: str, tensor: np.ndarray, shape: Sequence[int]) -> None:
    """Loading a tensor of the wrong shape must fail with the name, not deep inside a copy."""
    if tuple(tensor.shape) != tuple(shape):
        raise ValueError(f"tensor '{name}' has shape {list(tensor.shape)}, expected {list(shape)}")
