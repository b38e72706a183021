"""The treasure hunt as the package plays it: :class:`TreasureHunts`, R games stepped together by the
compiled rules (:mod:`dqn_transfer.envs.rules`), and :class:`TreasureHuntGame`, one game (its R = 1 view),
which the PettingZoo and Gymnasium faces wrap. Rules: docs/game.md.

Choices the specification leaves open, made here:

* ``reward_mode="team"``: every agent live before the step receives the sum of the step's
  rewards; agents that were already done receive 0 (they are not part of the transition).
* A non-live agent's observation stays its last one (the observation after its final move).
* ``competitive`` mode: an agent's ``treasures`` segment (and the chest plane of its ``view``)
  changes only when the agent itself enters a chest: taking it, finding it empty, or losing a
  tie there. Seeing a chest in the view window does *not* reveal its contents; the view shows what
  the agent believes.
* ``cooperative``/``deliberative``: every agent sees the true chest state.
* ``deliberative`` ties: agents are considered in index order; each gets the nearest chest
  (lowest chest number on equal distance), or none when there are more agents than chests, that
  still leaves a minimum-total assignment for the others (:func:`~dqn_transfer.envs.rules.best_assignment`).
  An agent that ends keeps its last assignment in its final observation.
* Two agents entering the same full chest in one step: the winner is drawn with the generator
  passed to :meth:`TreasureHuntGame.reset`; every loser gets ``step_reward`` and (in competitive
  mode) learns the chest is empty.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import fields
from typing import Any, NamedTuple, TypeGuard

import numpy as np

import dqn_transfer.envs.rules as rules
import dqn_transfer.envs.tie_draws as tie_draws
from dqn_transfer.enums import Mode, ObsEncoding, RewardMode, check_choice, check_enum
from dqn_transfer.envs.batch import BatchStep, GameBatch
from dqn_transfer.envs.maps import GridMap, resolve_map
from dqn_transfer.envs.rules import ACTION_MOVES
from dqn_transfer.envs.settings import DEFAULTS, MAP_KEYS, RULE_KEYS, EnvConfig

RENDER_MODES = ("ansi", "rgb_array", "human")  # human: the ansi frame printed to the terminal

CELL_PX = 16
COLOURS = {
    "free": (235, 235, 235),
    "obstacle": (60, 60, 60),
    "chest_full": (255, 196, 0),
    "chest_empty": (150, 110, 60),
    "trap": (200, 30, 30),
    "grid": (200, 200, 200),
}
AGENT_COLOURS = np.array(
    [
        (31, 119, 180),
        (44, 160, 44),
        (148, 103, 189),
        (23, 190, 207),
        (227, 119, 194),
        (255, 127, 14),
        (140, 86, 75),
        (127, 127, 127),
        (188, 189, 34),
        (0, 0, 128),
    ],
    dtype=np.uint8,
)


def check_render_mode(render_mode: str | None) -> str | None:
    if render_mode is not None:
        check_choice("render_mode", render_mode, RENDER_MODES)
    return render_mode


def _check_reward(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return float(value)


def _check_int(name: str, value: object, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _state_array(state: Mapping[str, Any], key: str, shape: tuple[int, ...], kinds: str, game: str) -> np.ndarray:
    """``state[key]`` as an array of ``shape`` and dtype kind in ``kinds``, else ``ValueError``."""
    try:
        value = np.asarray(state[key])
    except ValueError:  # ragged nested lists
        raise ValueError(f"game state {key!r} is ragged, expected shape {shape}: {game}") from None
    if value.shape != shape:
        raise ValueError(f"game state {key!r} has shape {value.shape}, expected {shape}: {game}")
    if value.size and value.dtype.kind not in kinds:
        wanted = {"b": "booleans", "iu": "integers", "fiu": "numbers"}[kinds]
        raise ValueError(f"game state {key!r} must hold {wanted}, got dtype {value.dtype}")
    return value


def _state_int(state: Mapping[str, Any], key: str, high: int) -> int:
    value = state[key]
    integer = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not integer or not 0 <= value <= high:
        raise ValueError(f"game state {key!r} must be an integer in 0..{high}, got {value!r}")
    return int(value)


class StepOutcome(NamedTuple):
    """What one joint step did, per agent (one row each; a non-live agent's row is zero / False)."""

    obs: np.ndarray  # [K, obs_dim] float32: every agent's observation after the step
    rewards: np.ndarray  # [K] float32
    terminated: np.ndarray  # [K] bool: ended in a chest or a trap
    truncated: np.ndarray  # [K] bool: still live at ``max_steps``
    trap: np.ndarray  # [K] bool: entered a trap
    treasures_collected: int  # chests emptied by this step
    live: np.ndarray  # [K] bool: who acts next
    bounced: np.ndarray  # [K] bool: moved into an obstacle, and so back to its own start

    @property
    def info(self) -> dict[str, Any]:
        """The Gymnasium-style info dict of the step."""
        return {
            "treasures_collected": self.treasures_collected,
            "trap": self.trap,
            "live": self.live,
            "bounced": self.bounced,
        }


class TreasureHunts(GameBatch):
    """R treasure hunts under one set of rules, stepped together by the compiled rules
    (:mod:`dqn_transfer.envs.rules`); replica r draws its chest ties from ``rngs[r]``. The maps may
    differ but share their size and chest count, and have at least ``num_agents`` starts.

    Its arrays (:attr:`obs`, :attr:`live`, a :class:`~dqn_transfer.envs.batch.BatchStep`'s) are new at
    every step and reset, so a caller may keep them. A replica whose episode is over stays as it is when
    stepped, until it is reset.

    The kernels draw the chest ties from a copy of each generator's state (``state.tie_rng``), made when
    the generator is handed over (here, :meth:`use_generator`) and written back after every step that
    drew (:meth:`keep_draws`): the generators are the games' while they play, drawn from nowhere else.
    """

    def __init__(
        self,
        grid_maps: Sequence[GridMap],
        rngs: Sequence[np.random.Generator] | None = None,
        *,
        mode: Mode | str = DEFAULTS.mode,
        reward_mode: RewardMode | str = DEFAULTS.reward_mode,
        obs_encoding: ObsEncoding | str = DEFAULTS.obs_encoding,
        view_radius: int = DEFAULTS.view_radius,
        max_steps: int | None = DEFAULTS.max_steps,
        treasure_reward: float = DEFAULTS.treasure_reward,
        trap_reward: float = DEFAULTS.trap_reward,
        step_reward: float = DEFAULTS.step_reward,
        num_agents: int | None = None,
        include_treasures: bool = True,
    ) -> None:
        """
        :param grid_maps: one map per replica (repeats allowed)
        :param rngs: replica r's generator of chest ties (None: each a ``default_rng(0)`` until reset)
        :param mode: competitive | cooperative | deliberative (docs/game.md)
        :param reward_mode: individual | team
        :param obs_encoding: onehot | coords, the ``position`` segment
        :param view_radius: the local view's radius (0: no view segment)
        :param max_steps: the episode's time limit (None: ``size * size``)
        :param treasure_reward: the reward of the agent that takes a chest
        :param trap_reward: the reward of an agent entering a trap
        :param step_reward: every other agent-step's reward
        :param num_agents: the first ``num_agents`` starts of each map play (None: all the first map's)
        :param include_treasures: the observation has the ``treasures`` segment
        """
        self.maps = tuple(grid_maps)
        if not self.maps:
            raise ValueError("a batch of treasure hunts needs at least one map")
        first = self.maps[0]
        shapes = sorted({(m.size, m.num_treasures) for m in self.maps})
        if len(shapes) > 1:
            named = "; ".join(f"size {n}, {k} chests" for n, k in shapes)
            raise ValueError(f"the maps of one batch must share their size and chest count; got {named}")
        map_agents = min(m.num_agents for m in self.maps)
        if num_agents is None:
            num_agents = first.num_agents
        integer = isinstance(num_agents, (int, np.integer)) and not isinstance(num_agents, bool)
        if not integer or not 1 <= num_agents <= map_agents:
            raise ValueError(f"num_agents must be between 1 and the map's {map_agents} starts, got {num_agents!r}")
        self.map = first
        self.size = n = first.size
        self.num_agents = int(num_agents)
        self.num_treasures = first.num_treasures
        self.num_actions = len(ACTION_MOVES)
        self.num_replicas = len(self.maps)
        self.mode = check_enum("mode", mode, Mode)
        self.reward_mode = check_enum("reward_mode", reward_mode, RewardMode)
        self.obs_encoding = check_enum("obs_encoding", obs_encoding, ObsEncoding)
        self.view_radius = _check_int("view_radius", view_radius, 0)
        self.max_steps = n * n if max_steps is None else _check_int("max_steps", max_steps, 1)
        self.treasure_reward = _check_reward("treasure_reward", treasure_reward)
        self.trap_reward = _check_reward("trap_reward", trap_reward)
        self.step_reward = _check_reward("step_reward", step_reward)
        self.include_treasures = bool(include_treasures)
        self._layout = rules.obs_layout(
            n, self.num_treasures, self.mode, self.obs_encoding, self.view_radius, self.include_treasures
        )
        self.obs_dim = sum(width for _, width in self._layout)
        self.tables = rules.build_tables(
            self.maps, self.num_agents, self.mode, self.obs_encoding, self.view_radius, self._layout
        )
        self._rewards = np.array([self.step_reward, self.trap_reward, self.treasure_reward], dtype=np.float32)
        self._team = self.reward_mode is RewardMode.team
        self._announce = self.mode is not Mode.competitive
        self.rngs = list(rngs) if rngs is not None else [np.random.default_rng(0) for _ in self.maps]
        if len(self.rngs) != self.num_replicas:
            raise ValueError(f"{len(self.rngs)} generators for {self.num_replicas} games")
        self.state = rules.State.empty(self.num_replicas, self.num_agents, self.num_treasures, self.obs_dim)
        for r, rng in enumerate(self.rngs):
            tie_draws.pack(rng, self.state.tie_rng[r])
        self._out = rules.Outcome.empty(self.num_replicas, self.num_agents, self.num_treasures)
        self._row = rules.arrays(self.tables, self.state, self._out)
        self.reset(np.ones(self.num_replicas, dtype=bool))

    @classmethod
    def of_games(cls, games: Sequence[TreasureHuntGame], rngs: Sequence[np.random.Generator]) -> TreasureHunts:
        """The games' replicas as one batch, each continuing its game's episode (games that
        :func:`fit_one_batch`); ``rngs[r]`` draws replica r's ties."""
        batch = cls([game.map for game in games], rngs, **games[0].settings())
        for r, game in enumerate(games):
            batch.load_state_dict(r, game.state_dict())
        return batch

    # ------------------------------------------------------------------ what a step reads
    @property
    def obs(self) -> np.ndarray:
        return self.state.obs

    @property
    def live(self) -> np.ndarray:
        return self.state.live

    def settings(self) -> dict:
        """The constructor arguments of these games, besides their maps and generators."""
        rule_values = {key: getattr(self, key) for key in RULE_KEYS}
        return dict(rule_values, num_agents=self.num_agents, include_treasures=self.include_treasures)

    def obs_layout(self) -> list[tuple[str, int]]:
        """Named observation segments, in order; the same for every agent."""
        return list(self._layout)

    # ------------------------------------------------------------------ dynamics
    def _fresh_arrays(self) -> None:
        """New ``obs`` and ``live`` arrays for the kernels to change (a caller may hold the old ones)."""
        s = self.state
        self.state = rules.State(
            s.pos,
            s.live.copy(),
            s.chest_full,
            s.belief,
            s.assigned,
            s.t,
            s.treasures_collected,
            s.obs.copy(),
            s.tie_rng,
            s.tie_drawn,
        )
        self._row = rules.arrays(self.tables, self.state, self._out)

    def step(self, actions: np.ndarray) -> BatchStep:
        """One joint step of every replica with ``actions [R, K]`` integers (non-live agents' are ignored)."""
        acts = np.asarray(actions)
        if acts.shape != (self.num_replicas, self.num_agents) or acts.dtype.kind not in "iu":
            raise ValueError(
                f"actions must be integers of shape {(self.num_replicas, self.num_agents)}, "
                f"got {acts.dtype} {acts.shape}"
            )
        out = self.advance(acts.astype(np.int64, copy=False))
        return BatchStep(
            next_obs=self.state.obs,
            rewards=out.rewards.copy(),
            terminated=out.terminated.copy(),
            truncated=out.truncated.copy(),
            trap=out.trap.copy(),
            bounced=out.bounced.copy(),
            treasures_collected=out.collected.copy(),
            episode_treasures=self.state.treasures_collected.copy(),
            episode_end=out.ended.copy(),
        )

    def advance(self, actions: np.ndarray) -> rules.Outcome:
        """The joint step of ``actions [R, K] int64``; the outcome's arrays are overwritten by the next one."""
        self._fresh_arrays()
        status = rules.step_arrays(actions, *self.rule_constants, *self._row)
        if status == rules.TIES_DRAWN:
            self.keep_draws()
        elif status == rules.BAD_ACTION:
            played = np.unique(actions[self.state.live]).tolist()
            raise ValueError(f"actions must be in 0..{self.num_actions - 1}, got {played}")
        return self._out

    @property
    def rule_constants(self) -> tuple[np.ndarray, int, bool, bool]:
        """What :func:`~dqn_transfer.envs.rules.step` takes besides the arrays: the rewards (step, trap,
        treasure, float32), ``max_steps``, team rewards, announced chests (every mode but competitive)."""
        return self._rewards, self.max_steps, self._team, self._announce

    def kernel_arrays(self) -> tuple[np.ndarray, ...]:
        """The row of arrays the rules' kernels take (:func:`~dqn_transfer.envs.rules.arrays`), with new
        ``obs`` and ``live`` arrays for them to change: a kernel that steps these games takes it (and
        :meth:`keep_draws` follows it)."""
        self._fresh_arrays()
        return self._row

    def use_generator(self, replica: int, rng: np.random.Generator) -> None:
        """Replica ``replica`` draws its chest ties from ``rng`` from now on."""
        tie_draws.pack(rng, self.state.tie_rng[replica])
        self.rngs[replica] = rng

    def restart(self, tie_rng: np.ndarray) -> None:
        """Start a new episode in every replica, replica r drawing its chest ties from the packed
        generator state ``tie_rng[r]`` (:mod:`~dqn_transfer.envs.tie_draws`) of no ``Generator``: the
        draws stay in :attr:`state` (:meth:`keep_draws` has nowhere to write them)."""
        self.state.tie_rng[:] = tie_rng
        self.state.tie_drawn[:] = False
        self.rngs = []
        self.reset(np.ones(self.num_replicas, dtype=bool))

    def keep_draws(self) -> None:
        """Write the tie draws the kernels made back into the generators (call it after a kernel that
        stepped these games)."""
        drawn = self.state.tie_drawn
        if self.rngs:  # else restarted from packed states only
            for r in np.flatnonzero(drawn).tolist():
                tie_draws.unpack(self.state.tie_rng[r], self.rngs[r])
        drawn[:] = False

    def reset(self, which: np.ndarray) -> None:
        """Start a new episode in the replicas of the mask ``which [R] bool``."""
        which = np.asarray(which, dtype=bool)
        if which.any():
            self._fresh_arrays()
            rules.reset_arrays(which, *self._row)

    # ------------------------------------------------------------------ one replica's episode
    def state_dict(self, replica: int) -> dict[str, Any]:
        """Replica ``replica``'s episode in progress as JSON-able plain values (its generator is the
        caller's, saved along with this)."""
        s, k = self.state, self.num_treasures
        return {
            "pos": s.pos[replica].tolist(),
            "live": s.live[replica].tolist(),
            "chest_full": s.chest_full[replica].tolist(),
            "belief": s.belief[replica, :, :k].tolist(),  # column k is a constant 0
            "assigned": s.assigned[replica].tolist(),
            "obs": s.obs[replica].tolist(),  # float32 -> exact Python floats: round-trips bit-exactly
            "t": int(s.t[replica]),
            "treasures_collected": int(s.treasures_collected[replica]),
        }

    def load_state_dict(self, replica: int, state: Mapping[str, Any]) -> None:
        """Continue a :meth:`state_dict`'s episode in replica ``replica``. Everything is checked before
        anything is assigned, so a state that does not fit the replica's game (another map or rules)
        raises ``ValueError`` and leaves the games as they were."""
        agents, k, cells = self.num_agents, self.num_treasures, self.size**2
        grid_map = self.maps[replica]
        game = f"this game has {agents} agents, {k} chests, obs_dim {self.obs_dim} on a {self.size} x {self.size} grid"
        if not isinstance(state, Mapping):
            raise ValueError(f"game state must be a mapping, got {type(state).__name__}")
        keys = {"pos", "live", "chest_full", "belief", "assigned", "obs", "t", "treasures_collected"}
        if set(state) != keys:
            missing, unknown = sorted(keys - set(state)), sorted(map(str, set(state) - keys))
            raise ValueError(f"game state keys do not match: missing {missing}, unknown {unknown}")
        pos = _state_array(state, "pos", (agents,), "iu", game)
        live = _state_array(state, "live", (agents,), "b", game)
        chest_full = _state_array(state, "chest_full", (k,), "b", game)
        belief = _state_array(state, "belief", (agents, k), "fiu", game)
        assigned = _state_array(state, "assigned", (agents,), "iu", game)
        obs = _state_array(state, "obs", (agents, self.obs_dim), "fiu", game)
        t = _state_int(state, "t", self.max_steps)
        collected = _state_int(state, "treasures_collected", k)
        outside = np.flatnonzero((pos < 0) | (pos >= cells))
        if outside.size:
            raise ValueError(
                f"game state 'pos' puts agent {int(outside[0])} at cell "
                f"{int(pos[outside[0]])}, outside the {self.size} x {self.size} grid"
            )
        cells_at = [divmod(cell, self.size) for cell in pos.tolist()]
        blocked = [a for a, cell in enumerate(cells_at) if cell in grid_map.obstacles]
        if blocked:
            raise ValueError(f"game state 'pos' puts agent {blocked[0]} on an obstacle of this map")
        if ((assigned < -1) | (assigned >= k)).any():
            raise ValueError(f"game state 'assigned' holds {assigned.tolist()}: chests are -1..{k - 1} here")
        for name, value in (("belief", belief), ("obs", obs)):
            if not np.array_equal(value.astype(np.float32), value):  # also rejects nan
                raise ValueError(f"game state {name!r} holds values that are not float32 numbers")
        self._fresh_arrays()
        s = self.state
        s.pos[replica], s.live[replica], s.chest_full[replica] = pos, live, chest_full
        s.belief[replica, :, :k], s.belief[replica, :, k] = belief, 0.0
        s.assigned[replica], s.obs[replica] = assigned, obs
        s.t[replica], s.treasures_collected[replica] = t, collected


def fit_one_batch(games: Sequence[Any]) -> TypeGuard[Sequence[TreasureHuntGame]]:
    """Whether ``games`` are treasure hunts one :class:`TreasureHunts` steps together (same size, chest
    count and rules; their maps may differ)."""
    first = games[0]
    return all(
        isinstance(game, TreasureHuntGame)
        and isinstance(first, TreasureHuntGame)
        and game.settings() == first.settings()
        and (game.size, game.num_treasures) == (first.size, first.num_treasures)
        for game in games
    )


class TreasureHuntGame:
    """One treasure hunt: K agents hunting the chests of one map (rules: :mod:`dqn_transfer.envs.rules`),
    the R = 1 view of :class:`TreasureHunts` behind the PettingZoo and Gymnasium faces, play, GIFs and
    the bounds. Arrays in, arrays out: ``reset(rng) -> obs [K, obs_dim]``, ``step(actions [K]) ->``
    :class:`StepOutcome`."""

    # The keys of an evaluation's record (rollout.summarize) this game measures, and those each
    # evaluation's console line and the loggers' eval/ tags show.
    evaluation_metrics = (
        "team_return",
        "success_rate",
        "trap_rate",
        "episode_length",
        "after_clear_rate",
        "return_after_clear",
    )
    headline_metrics = ("team_return", "success_rate", "trap_rate")
    # The keys each training episode's end logs as team/ tags besides the return (training.replica.EpisodeSums).
    episode_metrics = ("treasures_collected", "trap_rate")

    def __init__(self, grid_map: GridMap, **settings: Any) -> None:
        """
        :param grid_map: the map played
        :param settings: the rules, as :class:`TreasureHunts` takes them (``mode``, ``reward_mode``,
            ``obs_encoding``, ``view_radius``, ``max_steps``, the three rewards, ``num_agents``,
            ``include_treasures``)
        """
        self._games = games = TreasureHunts([grid_map], **settings)
        self._first = np.ones(1, dtype=bool)
        self.map = grid_map
        self.size, self.num_agents, self.num_treasures = games.size, games.num_agents, games.num_treasures
        self.num_actions, self.obs_dim, self.max_steps = games.num_actions, games.obs_dim, games.max_steps
        self.mode, self.reward_mode, self.obs_encoding = games.mode, games.reward_mode, games.obs_encoding
        self.view_radius, self.include_treasures = games.view_radius, games.include_treasures
        self.treasure_reward, self.trap_reward, self.step_reward = (
            games.treasure_reward,
            games.trap_reward,
            games.step_reward,
        )

    def obs_layout(self) -> list[tuple[str, int]]:
        """Named observation segments, in order; the same for every agent."""
        return self._games.obs_layout()

    def obs_offsets(self) -> dict[str, tuple[int, int]]:
        """Each observation segment's ``(start, end)`` columns."""
        offsets, start = {}, 0
        for name, width in self.obs_layout():
            offsets[name] = (start, start + width)
            start += width
        return offsets

    def position_codes(self) -> np.ndarray:
        """The ``position`` segment of each cell, row-major: ``[n * n, width]`` float32."""
        return self._games.tables.position_code.copy()

    def settings(self) -> dict:
        """The constructor arguments of this game, besides its map."""
        return self._games.settings()

    def recorded_env(self) -> dict[str, Any]:
        """What a checkpoint records of the game besides its config: the map as played (:func:`map_settings`)."""
        return map_settings(self.map)

    def identity(self) -> str:
        """The text a resumed run's game must match: the map's layout (a layout file may have changed since)."""
        return self.map.layout

    def replica(self) -> TreasureHuntGame:
        """An independent game with the same map and rules (e.g. for evaluation), built without
        resolving the map again."""
        return TreasureHuntGame(self.map, **self.settings())

    def single_agent_game(self) -> TreasureHuntGame:
        """The source task of transfer: agent 0 alone on this map, observing position [+ view]."""
        return TreasureHuntGame(
            self.map,
            **{
                **self.settings(),
                "mode": Mode.competitive,
                "reward_mode": RewardMode.individual,
                "num_agents": 1,
                "include_treasures": False,
            },
        )

    # ------------------------------------------------------------------ state
    @property
    def live(self) -> np.ndarray:
        return self._games.state.live[0].copy()

    @property
    def done(self) -> bool:
        return not self._games.state.live[0].any()

    @property
    def chest_full(self) -> np.ndarray:
        return self._games.state.chest_full[0].copy()

    @property
    def positions(self) -> np.ndarray:
        """``[K, 2]`` (row, col) of every agent."""
        return np.stack(np.divmod(self._games.state.pos[0], self.size), axis=1)

    @property
    def assignment(self) -> np.ndarray:
        """Chest assigned to each agent (deliberative mode; ``-1``: none)."""
        return self._games.state.assigned[0].copy()

    @property
    def steps(self) -> int:
        return int(self._games.state.t[0])

    @property
    def treasures_collected(self) -> int:
        """Chests emptied so far in the episode."""
        return int(self._games.state.treasures_collected[0])

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict[str, Any]:
        """The in-progress episode as JSON-able plain values, for checkpoints taken mid-episode.

        The tie generator is not in it: it is the caller's (passed to :meth:`reset`), and the caller
        saves its state along with this.
        """
        return self._games.state_dict(0)

    def load_state_dict(self, state: Mapping[str, Any], rng: np.random.Generator) -> np.ndarray:
        """Resume the episode of a :meth:`state_dict`, returning the current observation; ``rng``
        draws the later ties, as in :meth:`reset`. A state that does not fit this game (another map or
        rules) raises ``ValueError`` and leaves the game as it was."""
        self._games.load_state_dict(0, state)
        self._games.use_generator(0, rng)
        return self._games.state.obs[0].copy()

    # ------------------------------------------------------------------ dynamics
    def reset(self, rng: np.random.Generator) -> np.ndarray:
        """Agents to their starts, every chest full; ``rng`` draws the winners of chest ties."""
        self._games.use_generator(0, rng)
        self._games.reset(self._first)
        return self._games.state.obs[0].copy()

    def step(self, actions: np.ndarray) -> StepOutcome:
        """Move every live agent at once; actions of non-live agents are ignored."""
        games = self._games
        if not games.state.live[0].any():
            raise RuntimeError("the episode is over: call reset() before step()")
        acts = np.asarray(actions)
        if acts.shape != (self.num_agents,) or acts.dtype.kind not in "iu":
            raise ValueError(f"actions must be {self.num_agents} integers, got {acts.dtype} {acts.shape}")
        out = games.advance(acts.reshape(1, -1).astype(np.int64, copy=False))
        return StepOutcome(
            games.state.obs[0],  # new arrays each step: never changed afterwards
            out.rewards[0].copy(),
            out.terminated[0].copy(),
            out.truncated[0].copy(),
            out.trap[0].copy(),
            int(out.collected[0]),
            games.state.live[0],
            out.bounced[0].copy(),
        )

    # ------------------------------------------------------------------ rendering
    def render(self, render_mode: str | None) -> str | np.ndarray | None:
        """What both faces' ``render()`` return: text for ``ansi``, an RGB array for ``rgb_array``;
        ``human`` prints the text frame (a grid game's window is the terminal) and returns None."""
        if render_mode == "ansi":
            return self.render_ansi()
        if render_mode == "rgb_array":
            return self.render_rgb()
        if render_mode == "human":
            print(self.render_ansi(), end="\n\n", flush=True)
        return None

    def render_ansi(self) -> str:
        """The grid (``T`` full chest, ``t`` empty chest, digits: live agents, ``*``: several)."""
        live, chest_full = self.live, self.chest_full
        status = (
            f"step {self.steps}/{self.max_steps}  live agents: {np.flatnonzero(live).tolist()}  "
            f"full chests: {int(chest_full.sum())}/{self.num_treasures}"
        )
        return text_grid(self.map, self.positions, live, chest_full) + "\n" + status

    def render_rgb(self) -> np.ndarray:
        """``[n*16, n*16, 3]`` uint8 image: cells coloured by type, live agents drawn on top."""
        n, px = self.size, CELL_PX
        colour = np.empty((n, n, 3), dtype=np.uint8)
        colour[:] = COLOURS["free"]
        for r, c in self.map.obstacles:
            colour[r, c] = COLOURS["obstacle"]
        for r, c in self.map.traps:
            colour[r, c] = COLOURS["trap"]
        for chest, (r, c) in enumerate(self.map.chests):
            colour[r, c] = COLOURS["chest_full" if self._games.state.chest_full[0, chest] else "chest_empty"]
        img = np.repeat(np.repeat(colour, px, axis=0), px, axis=1)
        img[::px, :] = COLOURS["grid"]
        img[:, ::px] = COLOURS["grid"]
        pad = px // 4
        state = self._games.state
        for agent in np.flatnonzero(state.live[0]).tolist():
            r, c = divmod(int(state.pos[0, agent]), n)
            img[r * px + pad : (r + 1) * px - pad, c * px + pad : (c + 1) * px - pad] = AGENT_COLOURS[
                agent % len(AGENT_COLOURS)
            ]
        return img


def text_grid(grid_map: GridMap, positions: np.ndarray, live: np.ndarray, chest_full: np.ndarray) -> str:
    """The map's rows with the chests' state (``T`` full, ``t`` empty) and the live agents (their digit,
    ``*`` where several stand): the text frame of a game state, live or recorded."""
    grid = [["." if ch.isdigit() else ch for ch in row] for row in grid_map.rows]
    for chest, (r, c) in enumerate(grid_map.chests):
        grid[r][c] = "T" if chest_full[chest] else "t"
    for agent in np.flatnonzero(live).tolist():
        r, c = (int(x) for x in positions[agent])
        grid[r][c] = "*" if grid[r][c].isdigit() else str(agent)
    return "\n".join("".join(row) for row in grid)


def make_game(**settings) -> TreasureHuntGame:
    """The game for the ``env`` keys of :class:`~dqn_transfer.envs.settings.EnvConfig` (the trainer's
    ``env`` config group), each defaulting to its value there.

    ``render_mode`` is only validated here (rendering belongs to the faces), so a whole env config
    can be passed as it is. A map key left out is "not given": with a layout, only the given ones
    that disagree with it are warned about.
    """
    unknown = sorted(set(settings) - {f.name for f in fields(EnvConfig)})
    if unknown:
        raise TypeError(f"unknown env setting(s) {', '.join(unknown)}")
    config = EnvConfig(**settings)
    check_render_mode(config.render_mode)
    return game_on(resolve_map(**{key: settings.get(key) for key in MAP_KEYS}), config)


def game_on(grid_map: GridMap, config: EnvConfig) -> TreasureHuntGame:
    """The game of ``config``'s rules on ``grid_map`` (the map ``config``'s map keys resolve to)."""
    return TreasureHuntGame(grid_map, **{key: getattr(config, key) for key in RULE_KEYS})


def map_settings(grid_map: GridMap) -> dict[str, Any]:
    """The map keys of :class:`~dqn_transfer.envs.settings.EnvConfig` (``MAP_KEYS``) that rebuild
    ``grid_map`` from its layout alone: ``make_game(**settings)`` plays this very map, whatever the
    generation settings or the layout file were (those are left unset)."""
    played = {
        "layout": grid_map.layout,
        "size": grid_map.size,
        "num_treasures": grid_map.num_treasures,
        "num_traps": grid_map.num_traps,
        "num_agents": grid_map.num_agents,
    }
    return {key: played.get(key) for key in MAP_KEYS}
