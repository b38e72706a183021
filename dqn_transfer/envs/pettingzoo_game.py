"""Any PettingZoo ``ParallelEnv`` as a game the trainer can play (docs/your_own_environment.md).

:class:`PettingZooGame` gives an outside env the interface the trainer, the evaluation and the checkpoints
use of :class:`~dqn_transfer.envs.game.TreasureHuntGame`: ``K`` agents (the env's ``possible_agents``),
``reset(rng)`` and ``step(actions)`` on arrays, a :class:`~dqn_transfer.envs.game.StepOutcome` per step,
``live`` / ``done``, ``obs_layout()`` and ``state_dict()`` for a checkpoint taken mid-episode.

Choices made here:

* Observations are flattened to float32: a ``Box`` as it is, a ``Discrete(n)`` as a one-hot of ``n``, a
  ``MultiDiscrete`` as one one-hot per entry. Agents whose observations are narrower than the widest
  are padded with zeros to it. ``Dict``, ``Tuple`` and other spaces, and observations wider than
  :data:`MAX_OBS_WIDTH` (images: use a CNN library) are refused.
* Actions must be ``Discrete``. An agent with fewer actions than the team's largest ``n`` plays action
  ``a mod n_i`` for ``a``: its extra actions are copies of its own (padded, not masked), so every
  agent's Q-network has ``n`` outputs and learns the same values for copies.
* An agent is live while it is in the env's ``agents`` and has neither terminated nor been truncated;
  an agent that leaves keeps its last observation, gets reward 0 and is not part of later transitions.
  Agents that join mid-episode are not supported (PettingZoo envs rarely have them).
* Rewards are per agent (``reward_mode`` individual); the team return is their sum over live agents.
* Episodes are seeded: ``reset(rng)`` draws the env's seed from ``rng``, or, for a game made with a
  ``reset_seed`` (``env.fixed_start``), resets with that seed every episode: one fixed *instance* of
  the env, the counterpart of the treasure hunt's map (a map seed, one instance). A checkpoint taken mid-episode
  records that seed and the joint actions played since, and :meth:`PettingZooGame.load_state_dict`
  replays them, so any env that is deterministic given its seed resumes bit-identically without
  serialising its state; the replayed observation is compared with the recorded one, so an env that is
  not deterministic is refused rather than resumed differently.
* An env may declare its observation's named segments (``observation_segments``: ``(name, width)``
  pairs summing to the width), which transfer maps by name (the LBF adapter does:
  :mod:`dqn_transfer.envs.lbf`); otherwise the layout is one segment ``obs``.
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv
from pettingzoo.utils.conversions import aec_to_parallel

from dqn_transfer.enums import EXTRA_MODULES, RewardMode
from dqn_transfer.envs.game import StepOutcome

# The widest flattened observation an MLP learner is given (a 64x64 RGB image is 12288 wide).
MAX_OBS_WIDTH = 4096
SEED_RANGE = 2**31 - 1
RGB_ARRAY = "rgb_array"  # the render mode whose frames dqn-transfer-play writes to a GIF
SUPPORTED_OBSERVATIONS = "Box, Discrete or MultiDiscrete"


class UnsupportedEnv(ValueError):
    """An env (or its factory) the adapter cannot play; the message is one user-facing line."""


def load_factory(spec: str) -> Any:
    """The callable ``PACKAGE.MODULE:CALLABLE`` names.

    :param spec: where the callable lives, e.g. ``mpe2.simple_spread_v3:parallel_env``.
    """
    module_name, _, attribute = spec.partition(":")
    if not module_name or not attribute:
        raise UnsupportedEnv(f"env.factory={spec}: expected PACKAGE.MODULE:CALLABLE")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        extra = EXTRA_MODULES.get(str(err.name).split(".")[0])
        hint = f"; {extra.install}" if extra is not None else ""
        raise UnsupportedEnv(f"env.factory={spec}: cannot import {module_name} ({err}){hint}") from None
    factory = getattr(module, attribute, None)
    if not callable(factory):
        raise UnsupportedEnv(f"env.factory={spec}: {module_name} has no callable {attribute}")
    return factory


def make_parallel_env(spec: str, kwargs: Mapping[str, Any]) -> Any:
    """The env ``spec``'s factory returns for ``kwargs``, checked to be a ParallelEnv; a parallelizable AEC env
    is converted to one.

    :param spec: ``PACKAGE.MODULE:CALLABLE``.
    :param kwargs: keyword arguments of the factory.
    """
    factory = load_factory(spec)
    try:
        env = factory(**kwargs)
    except Exception as err:  # the factory is the user's: any refusal of its arguments is theirs to read
        raise UnsupportedEnv(
            f"env.factory={spec} refused env.kwargs={dict(kwargs)}: {type(err).__name__}: {err}"
        ) from None
    if isinstance(env, AECEnv):
        # An AEC env whose agents all act before it updates, as its author declares with
        # is_parallelizable, is the same game in parallel (mpe2's parallel_env is exactly this wrapper of
        # its env); of any other, agents' turns see each other's moves, which no joint step can express.
        if not env.metadata.get("is_parallelizable", False):
            raise UnsupportedEnv(
                f"env.factory={spec} returned an AEC env whose metadata does not declare is_parallelizable: "
                "give the factory of a PettingZoo ParallelEnv (e.g. the package's parallel_env)"
            )
        return aec_to_parallel(env)
    missing = [
        name
        for name in ("possible_agents", "reset", "step", "observation_space", "action_space")
        if not hasattr(env, name)
    ]
    if missing:
        raise UnsupportedEnv(
            f"env.factory={spec} returned a {type(env).__name__}, not a PettingZoo ParallelEnv "
            f"(no {', '.join(missing)}); an AEC env converts with pettingzoo.utils.aec_to_parallel"
        )
    return env


def observation_width(space: spaces.Space, where: str) -> int:
    """The flattened float width of an observation space, or :class:`UnsupportedEnv` naming it.

    :param space: one agent's observation space.
    :param where: the agent and env, for the message.
    """
    if isinstance(space, spaces.Box):
        width = int(np.prod(space.shape))
    elif isinstance(space, spaces.Discrete):
        width = int(space.n)
    elif isinstance(space, spaces.MultiDiscrete) and space.nvec.ndim == 1:
        width = int(space.nvec.sum())
    else:
        raise UnsupportedEnv(f"{where} observes a {space}: supported observations are {SUPPORTED_OBSERVATIONS}")
    if width > MAX_OBS_WIDTH:
        raise UnsupportedEnv(
            f"{where} observes a {space}: {width} floats flattened, more than an MLP learner takes "
            f"({MAX_OBS_WIDTH}); downsample it (SuperSuit's resize / color_reduction) or use a CNN library"
        )
    return width


def flatten_observation(space: spaces.Space, observation: Any, width: int) -> np.ndarray:
    """``observation`` of ``space`` as float32 of ``width`` (one-hot for discrete spaces, zero padding).

    :param space: the agent's observation space.
    :param observation: what the env returned.
    :param width: the team's widest flattened observation.
    """
    flat = np.zeros(width, dtype=np.float32)
    if isinstance(space, spaces.Box):
        values = np.asarray(observation, dtype=np.float32).reshape(-1)
        flat[: values.size] = values
    elif isinstance(space, spaces.Discrete):
        flat[int(observation) - int(space.start)] = 1.0
    elif isinstance(space, spaces.MultiDiscrete):
        offsets = np.concatenate([[0], np.cumsum(space.nvec)[:-1]])
        flat[offsets + np.asarray(observation, dtype=np.int64) - space.start] = 1.0
    return flat


class PettingZooGame:
    """A PettingZoo ParallelEnv stepped through the treasure hunt's game interface (module docstring).

    :param factory: ``PACKAGE.MODULE:CALLABLE`` returning the ParallelEnv.
    :param kwargs: keyword arguments of the factory.
    :param reset_seed: every episode's reset seed (a fixed instance); None: drawn each episode.
    """

    reward_mode = RewardMode.individual
    num_treasures = 0  # no chests: evaluation's success_rate is 0 (docs/your_own_environment.md)
    # What the game measures (TreasureHuntGame's): its record's chest and trap keys stay, at 0, but
    # the console and the loggers show only these.
    evaluation_metrics = headline_metrics = ("team_return", "episode_length")
    episode_metrics = ()  # an episode's end logs only the team's return: no chests, no traps
    treasures_collected = 0

    def __init__(self, factory: str, kwargs: Mapping[str, Any], reset_seed: int | None = None) -> None:
        self.factory, self.kwargs, self.reset_seed = factory, dict(kwargs), reset_seed
        self.env = make_parallel_env(factory, self.kwargs)
        self.agents = list(self.env.possible_agents)
        self.num_agents = len(self.agents)
        if self.num_agents == 0:
            raise UnsupportedEnv(f"env.factory={factory}: the env has no possible_agents")
        self.observation_spaces = [self.env.observation_space(agent) for agent in self.agents]
        self.action_spaces = [self.env.action_space(agent) for agent in self.agents]
        for agent, space in zip(self.agents, self.action_spaces):
            if not isinstance(space, spaces.Discrete):
                raise UnsupportedEnv(
                    f"env.factory={factory}: agent {agent} acts in a {space}: the learners need Discrete actions "
                    "(a continuous-action env often has a discrete option, e.g. continuous_actions=false)"
                )
        widths = [
            observation_width(s, f"env.factory={factory}: agent {a}")
            for a, s in zip(self.agents, self.observation_spaces)
        ]
        self.obs_dim = max(widths)
        self.action_counts = np.array([int(space.n) for space in self.action_spaces], dtype=np.int64)
        self.num_actions = int(self.action_counts.max())
        self._layout = self._declared_layout()
        self._obs = np.zeros((self.num_agents, self.obs_dim), dtype=np.float32)
        self._live = np.zeros(self.num_agents, dtype=bool)
        self._seed = 0
        self._actions: list[list[int]] = []  # the joint actions of the episode so far, for state_dict

    def _declared_layout(self) -> list[tuple[str, int]]:
        """The env's ``observation_segments`` if it declares them (checked), else one segment ``obs``."""
        declared = getattr(self.env, "observation_segments", None)
        if declared is None:
            return [("obs", self.obs_dim)]
        layout = [(str(name), int(width)) for name, width in declared]
        if sum(width for _, width in layout) != self.obs_dim:
            raise UnsupportedEnv(
                f"env.factory={self.factory}: its observation_segments {layout} do not add up to the "
                f"observation's width {self.obs_dim}"
            )
        return layout

    # ------------------------------------------------------------------ what the trainer reads
    def obs_layout(self) -> list[tuple[str, int]]:
        """Named observation segments, in order; the same for every agent."""
        return list(self._layout)

    @property
    def live(self) -> np.ndarray:
        return self._live.copy()

    @property
    def done(self) -> bool:
        return not self._live.any()

    @property
    def steps(self) -> int:
        return len(self._actions)

    def recorded_env(self) -> dict[str, Any]:
        """What a checkpoint records of the game: the factory, its kwargs, every agent's spaces, and a fixed
        instance's reset seed (only then: a game without one records what it did before the key existed)."""
        recorded = {
            "factory": self.factory,
            "kwargs": self.kwargs,
            "observation_spaces": [repr(space) for space in self.observation_spaces],
            "action_spaces": [repr(space) for space in self.action_spaces],
        }
        return recorded if self.reset_seed is None else {**recorded, "reset_seed": self.reset_seed}

    def identity(self) -> str:
        """The text a resumed run's game must match: :meth:`recorded_env` as JSON."""
        return json.dumps(self.recorded_env(), sort_keys=True)

    def replica(self) -> PettingZooGame:
        """An independent game from the same factory, kwargs and instance (e.g. for evaluation)."""
        return PettingZooGame(self.factory, self.kwargs, self.reset_seed)

    # ------------------------------------------------------------------ pictures
    @property
    def draws(self) -> bool:
        """Whether the env was made to draw RGB frames (``render_mode="rgb_array"`` in its kwargs)."""
        return self.kwargs.get("render_mode") == RGB_ARRAY

    def drawing(self) -> PettingZooGame:
        """The same game made with ``render_mode="rgb_array"``, checked to draw a frame after a reset;
        :class:`UnsupportedEnv` (one line) if the env has no such mode or cannot draw here (e.g. no display)."""
        modes = list(getattr(self.env, "metadata", {}).get("render_modes", []))
        if RGB_ARRAY not in modes:
            raise UnsupportedEnv(
                f"env.factory={self.factory}: the env cannot draw an RGB frame (its metadata's render_modes "
                f"are {modes}, without {RGB_ARRAY})"
            )
        game = PettingZooGame(self.factory, {**self.kwargs, "render_mode": RGB_ARRAY}, self.reset_seed)
        game.reset(np.random.default_rng(0))
        game.frame()
        return game

    def frame(self) -> np.ndarray:
        """The env's picture of the current state, ``[H, W, 3]`` uint8 (:meth:`drawing`'s game); an env that
        fails to draw is :class:`UnsupportedEnv` naming the env and its error."""
        try:
            picture = self.env.render()
        except Exception as err:  # the env's renderer is the user's: any failure (no display, ...) is one line
            reason = " ".join(str(err).split())  # one line
            raise UnsupportedEnv(
                f"env.factory={self.factory}: the env cannot draw an RGB frame here ({type(err).__name__}: {reason})"
            ) from None
        array = np.asarray(picture if picture is not None else [])
        if array.ndim != 3 or array.shape[2] not in (3, 4):
            raise UnsupportedEnv(
                f"env.factory={self.factory}: render() returned {type(picture).__name__} of shape "
                f"{array.shape}, not an RGB frame [H, W, 3]"
            )
        return np.ascontiguousarray(array[:, :, :3], dtype=np.uint8)

    # ------------------------------------------------------------------ dynamics
    def _observe(self, observations: Mapping[str, Any]) -> None:
        for i, agent in enumerate(self.agents):
            if agent in observations:
                self._obs[i] = flatten_observation(self.observation_spaces[i], observations[agent], self.obs_dim)

    def _reset_env(self, seed: int) -> np.ndarray:
        observations, _ = self.env.reset(seed=seed)
        self._seed, self._actions = seed, []
        self._obs[:] = 0.0
        self._observe(observations)
        present = set(self.env.agents)
        self._live[:] = [agent in present for agent in self.agents]
        return self._obs.copy()

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        """A new episode, the env seeded from ``rng`` (or with the instance's ``reset_seed``, ``rng`` untouched);
        returns every agent's observation ``[K, D]``.

        :param rng: draws the env's seed.
        """
        return self._reset_env(int(rng.integers(SEED_RANGE)) if self.reset_seed is None else self.reset_seed)

    def step(self, actions: np.ndarray) -> StepOutcome:
        """Every live agent acts (action ``a`` is ``a mod n_i`` for an agent with ``n_i`` actions).

        :param actions: ``[K]`` integers in ``0..num_actions-1``; those of non-live agents are ignored.
        """
        idx = np.flatnonzero(self._live)
        if idx.size == 0:
            raise RuntimeError("the episode is over: call reset() before step()")
        joint = np.asarray(actions, dtype=np.int64) % self.action_counts
        self._actions.append(joint.tolist())
        observations, rewards, terminations, truncations, _ = self.env.step(
            {self.agents[i]: int(joint[i]) for i in idx.tolist()}
        )
        self._observe(observations)
        k = self.num_agents
        reward = np.zeros(k, dtype=np.float32)
        terminated, truncated = np.zeros(k, dtype=bool), np.zeros(k, dtype=bool)
        present = set(self.env.agents)
        for i in idx.tolist():
            agent = self.agents[i]
            reward[i] = float(rewards.get(agent, 0.0))
            terminated[i] = bool(terminations.get(agent, False))
            truncated[i] = bool(truncations.get(agent, False)) and not terminated[i]
            if agent not in present and not (terminated[i] or truncated[i]):
                terminated[i] = True  # left without saying why: the env removed it, as a termination does
        self._live[idx] = ~(terminated[idx] | truncated[idx])
        trap, bounced = np.zeros(k, dtype=bool), np.zeros(k, dtype=bool)  # the treasure hunt's own events
        return StepOutcome(self._obs.copy(), reward, terminated, truncated, trap, 0, self._live.copy(), bounced)

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict[str, Any]:
        """The episode in progress as its seed and the joint actions played since, with the current
        observation and live flags to check the replay against (JSON-able plain values)."""
        return {
            "seed": self._seed,
            "actions": [list(a) for a in self._actions],
            "obs": self._obs.tolist(),
            "live": self._live.tolist(),
        }

    def load_state_dict(self, state: Mapping[str, Any], rng: np.random.Generator) -> np.ndarray:
        """Replay a :meth:`state_dict`'s episode and return its current observation; refuses (``ValueError``)
        a replay that does not reach the recorded observation (an env that is not deterministic given
        its seed). ``rng`` is not drawn from (the seed is in the state).

        :param state: a :meth:`state_dict`.
        :param rng: the generator later resets draw from (unused here; the treasure hunt's signature).
        """
        self._reset_env(int(state["seed"]))
        for joint in state["actions"]:
            self.step(np.asarray(joint, dtype=np.int64))
        recorded = np.asarray(state["obs"], dtype=np.float32)
        if not (np.array_equal(recorded, self._obs) and self._live.tolist() == list(state["live"])):
            raise ValueError(
                f"env.factory={self.factory}: replaying the episode from its seed did not reach the checkpoint's "
                "observation: the env is not deterministic given its reset seed, so it cannot resume mid-episode"
            )
        return self._obs.copy()
