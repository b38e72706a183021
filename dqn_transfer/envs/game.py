"""The treasure-hunt game: a pure numpy core stepping K agents at once (rules: docs/game.md).

The trainer drives :class:`TreasureHuntGame` directly (arrays in, arrays out); the PettingZoo and
Gymnasium faces are thin wrappers around it. Everything that does not change during a run is
precomputed once per map (next-cell tables, BFS distances, view windows) so a step is a handful
of numpy fancy-indexing operations, with a Python slow path only on steps where an agent enters a
chest or a trap.

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
  still leaves a minimum-total assignment for the others (see :func:`assign_agents`). An agent
  that ends keeps its last assignment in its final observation.
* Two agents entering the same full chest in one step: the winner is drawn with the generator
  passed to :meth:`TreasureHuntGame.reset`; every loser gets ``step_reward`` and (in competitive
  mode) learns the chest is empty.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import fields
from typing import Any, NamedTuple

import numpy as np

from dqn_transfer.enums import Mode, ObsEncoding, RewardMode, check_choice, check_enum
from dqn_transfer.envs.maps import GridMap, resolve_map
from dqn_transfer.envs.settings import DEFAULTS, MAP_KEYS, RULE_KEYS, EnvConfig

RENDER_MODES = ("ansi", "rgb_array", "human")  # human: the ansi frame printed to the terminal
ACTION_MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # 0 up, 1 down, 2 left, 3 right

_FREE, _CHEST, _TRAP = 0, 1, 2  # what a move can land on (an obstacle sends the agent home)

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


def _best_matching(cost: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Minimum-cost maximum matching of ``rows`` to ``cols``: (pairs, total, rows, cols)."""
    if len(rows) == 0 or len(cols) == 0:
        return 0, 0, rows[:0], cols[:0]
    # Imported here: scipy.optimize is 0.65 s of every process's start-up, and only the deliberative
    # mode's coordinator uses it.
    from scipy.optimize import linear_sum_assignment

    sub = cost[np.ix_(rows, cols)]
    r, c = linear_sum_assignment(sub)
    return len(r), int(sub[r, c].sum()), rows[r], cols[c]


def assign_agents(cost: np.ndarray) -> np.ndarray:
    """Chest column for each agent row (``-1``: none) minimising the total integer ``cost``.

    Among the optimal assignments, ties go to the lower agent index: agents are fixed in index
    order, each to its most preferred option -- cheapest chest, then lowest column, then no chest
    (only possible with more agents than chests) -- for which the remaining agents can still
    complete an assignment of minimum total. Exact on integers; a few small
    ``linear_sum_assignment`` calls, done only when chests or live agents change.
    """
    num_rows, num_cols = cost.shape
    all_rows, all_cols = np.arange(num_rows), np.arange(num_cols)
    pairs, best, rows, cols = _best_matching(cost, all_rows, all_cols)
    # One optimal assignment, kept consistent with the choices fixed so far.
    current = np.full(num_rows, -1, dtype=np.int64)
    current[rows] = cols
    fixed_pairs, fixed_cost, free_cols = 0, 0, list(range(num_cols))
    for agent in range(num_rows):
        options = sorted(free_cols, key=lambda c: (cost[agent, c], c))
        if num_rows > num_cols:
            options.append(-1)
        rest_rows = all_rows[agent + 1 :]
        for option in options:
            if option == current[agent]:
                break  # the assignment in hand already makes this choice
            own_pairs, own_cost = (1, int(cost[agent, option])) if option >= 0 else (0, 0)
            rest_cols = np.array([c for c in free_cols if c != option], dtype=np.int64)
            n, total, rows, cols = _best_matching(cost, rest_rows, rest_cols)
            if fixed_pairs + own_pairs + n == pairs and fixed_cost + own_cost + total == best:
                current[rest_rows] = -1
                current[rows] = cols
                current[agent] = option
                break
        if current[agent] >= 0:
            fixed_pairs += 1
            fixed_cost += int(cost[agent, current[agent]])
            free_cols.remove(int(current[agent]))
    return current


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


class TreasureHuntGame:
    """K agents hunting the chests of one map; see the module docstring for the rules' details."""

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
    # The keys each training episode's end logs as team/ tags besides the return (Replica._log_episode).
    episode_metrics = ("treasures_collected", "trap_rate")

    def __init__(
        self,
        grid_map: GridMap,
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
        self.map = grid_map
        self.mode = check_enum("mode", mode, Mode)
        self.reward_mode = check_enum("reward_mode", reward_mode, RewardMode)
        self.obs_encoding = check_enum("obs_encoding", obs_encoding, ObsEncoding)
        self.view_radius = _check_int("view_radius", view_radius, 0)
        n = grid_map.size
        self.size = n
        self.max_steps = n * n if max_steps is None else _check_int("max_steps", max_steps, 1)
        self.treasure_reward = _check_reward("treasure_reward", treasure_reward)
        self.trap_reward = _check_reward("trap_reward", trap_reward)
        self.step_reward = _check_reward("step_reward", step_reward)
        if num_agents is None:
            num_agents = grid_map.num_agents
        elif isinstance(num_agents, bool) or not 1 <= num_agents <= grid_map.num_agents:
            raise ValueError(
                f"num_agents must be between 1 and the map's {grid_map.num_agents} starts, got {num_agents!r}"
            )
        self.num_agents = int(num_agents)
        self.num_treasures = grid_map.num_treasures
        self.num_actions = len(ACTION_MOVES)
        self.include_treasures = bool(include_treasures)
        self._build_tables()
        self._build_obs_layout()
        k, agents = self.num_treasures, self.num_agents
        self._pos = self._starts.copy()
        self._live = np.ones(agents, dtype=bool)
        self._live_idx = np.arange(agents)
        self._chest_full = np.ones(k, dtype=bool)
        # Each agent's belief about each chest, plus a constant-0 column k: the "no chest" entry
        # the view's chest plane indexes for cells without a chest.
        self._belief = np.zeros((agents, k + 1), dtype=np.float32)
        self._assigned = np.full(agents, -1, dtype=np.int64)
        self._obs = np.zeros((agents, self.obs_dim), dtype=np.float32)
        self._rng = np.random.default_rng(0)
        self._t = 0
        self.treasures_collected = 0

    # ------------------------------------------------------------------ precomputation
    def _build_tables(self) -> None:
        n, gm = self.size, self.map
        cells = n * n
        flat = lambda cell: cell[0] * n + cell[1]  # noqa: E731
        obstacle = np.zeros(cells, dtype=bool)
        obstacle[[flat(c) for c in gm.obstacles]] = True
        self._kind = np.full(cells, _FREE, dtype=np.int8)
        self._kind[[flat(c) for c in gm.traps]] = _TRAP
        self._kind[[flat(c) for c in gm.chests]] = _CHEST
        self._chest_of = np.full(cells, self.num_treasures, dtype=np.int64)  # k = no chest
        self._chest_of[[flat(c) for c in gm.chests]] = np.arange(self.num_treasures)
        self._starts = np.array([flat(c) for c in gm.starts[: self.num_agents]], dtype=np.int64)
        self._coords = np.stack(np.divmod(np.arange(cells), n), axis=1).astype(np.float32) / (n - 1)

        rows, cols = np.divmod(np.arange(cells), n)
        moves = np.empty((cells, len(ACTION_MOVES)), dtype=np.int64)
        for a, (dr, dc) in enumerate(ACTION_MOVES):
            rr, cc = rows + dr, cols + dc
            inside = (rr >= 0) & (rr < n) & (cc >= 0) & (cc < n)
            moves[:, a] = np.where(inside, rr * n + cc, np.arange(cells))  # off-grid: stay
        # Per agent, because bumping into an obstacle sends an agent to its own start.
        self._bounce = obstacle[moves]  # [cells, 4]: the move runs into an obstacle
        self._next = np.where(self._bounce[None], self._starts[:, None, None], moves[None])

        if self.mode is Mode.deliberative:
            unreachable = self.num_agents * cells  # worse than any assignment of reachable pairs
            dist = np.stack([gm.distances_from(c).reshape(-1) for c in gm.chests])
            self._chest_dist = np.where(dist < 0, unreachable, dist)

        r = self.view_radius
        if r > 0:
            span = np.arange(-r, r + 1)
            wr = rows[:, None, None] + span[None, :, None]  # [cells, W, 1]
            wc = cols[:, None, None] + span[None, None, :]  # [cells, 1, W]
            inside = (wr >= 0) & (wr < n) & (wc >= 0) & (wc < n)
            idx = np.where(inside, np.clip(wr, 0, n - 1) * n + np.clip(wc, 0, n - 1), 0)
            idx = idx.reshape(cells, -1)
            inside = inside.reshape(cells, -1)
            blocked = np.where(inside, obstacle[idx], True)
            trap = inside & (self._kind[idx] == _TRAP)
            self._view_static = np.concatenate([blocked, trap], axis=1).astype(np.float32)
            self._view_chest = np.where(inside, self._chest_of[idx], self.num_treasures)

    def _build_obs_layout(self) -> None:
        k = self.num_treasures
        layout = [("position", self.size**2 if self.obs_encoding is ObsEncoding.onehot else 2)]
        if self.include_treasures:
            layout.append(("treasures", k))
        if self.mode is Mode.deliberative:
            layout.append(("assignment", k))
        if self.view_radius > 0:
            layout.append(("view", 3 * (2 * self.view_radius + 1) ** 2))
        self._layout = layout
        offsets, start = {}, 0
        for name, width in layout:
            offsets[name] = (start, start + width)
            start += width
        self._offsets = offsets
        self.obs_dim = start

    def obs_layout(self) -> list[tuple[str, int]]:
        """Named observation segments, in order; the same for every agent."""
        return list(self._layout)

    def obs_offsets(self) -> dict[str, tuple[int, int]]:
        """Each observation segment's ``(start, end)`` columns."""
        return dict(self._offsets)

    def position_codes(self) -> np.ndarray:
        """The ``position`` segment of each cell, row-major: ``[n * n, width]`` float32."""
        if self.obs_encoding is ObsEncoding.onehot:
            return np.eye(self.size**2, dtype=np.float32)
        return self._coords.copy()

    def settings(self) -> dict:
        """The constructor arguments of this game, besides its map."""
        rules = {key: getattr(self, key) for key in RULE_KEYS}
        return dict(rules, num_agents=self.num_agents, include_treasures=self.include_treasures)

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
        return self._live.copy()

    @property
    def done(self) -> bool:
        return self._live_idx.size == 0

    @property
    def chest_full(self) -> np.ndarray:
        return self._chest_full.copy()

    @property
    def positions(self) -> np.ndarray:
        """``[K, 2]`` (row, col) of every agent."""
        return np.stack(np.divmod(self._pos, self.size), axis=1)

    @property
    def assignment(self) -> np.ndarray:
        """Chest assigned to each agent (deliberative mode; ``-1``: none)."""
        return self._assigned.copy()

    @property
    def steps(self) -> int:
        return self._t

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict[str, Any]:
        """The in-progress episode as JSON-able plain values, for checkpoints taken mid-episode.

        The tie generator is not in it: it is the caller's (passed to :meth:`reset`), and the caller
        saves its state along with this.
        """
        return {
            "pos": self._pos.tolist(),
            "live": self._live.tolist(),
            "chest_full": self._chest_full.tolist(),
            "belief": self._belief[:, : self.num_treasures].tolist(),  # column k is a constant 0
            "assigned": self._assigned.tolist(),
            "obs": self._obs.tolist(),  # float32 -> exact Python floats: round-trips bit-exactly
            "t": self._t,
            "treasures_collected": self.treasures_collected,
        }

    def load_state_dict(self, state: Mapping[str, Any], rng: np.random.Generator) -> np.ndarray:
        """Resume the episode of a :meth:`state_dict`, returning the current observation; ``rng``
        draws the later ties, as in :meth:`reset`.

        Everything is checked before anything is assigned, so a state that does not fit this game
        (another map or rules) raises ``ValueError`` and leaves the game as it was.
        """
        agents, k, cells = self.num_agents, self.num_treasures, self.size**2
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
        blocked = [a for a, cell in enumerate(cells_at) if cell in self.map.obstacles]
        if blocked:
            raise ValueError(f"game state 'pos' puts agent {blocked[0]} on an obstacle of this map")
        if ((assigned < -1) | (assigned >= k)).any():
            raise ValueError(f"game state 'assigned' holds {assigned.tolist()}: chests are -1..{k - 1} here")
        for name, value in (("belief", belief), ("obs", obs)):
            if not np.array_equal(value.astype(np.float32), value):  # also rejects nan
                raise ValueError(f"game state {name!r} holds values that are not float32 numbers")
        self._rng = rng
        self._pos[:] = pos
        self._live[:] = live
        self._live_idx = np.flatnonzero(self._live)
        self._chest_full[:] = chest_full
        self._belief[:, :k] = belief
        self._assigned[:] = assigned
        self._obs[:] = obs
        self._t = t
        self.treasures_collected = collected
        return self._obs.copy()

    # ------------------------------------------------------------------ dynamics
    def reset(self, rng: np.random.Generator) -> np.ndarray:
        """Agents to their starts, every chest full; ``rng`` draws the winners of chest ties."""
        self._rng = rng
        self._pos[:] = self._starts
        self._live[:] = True
        self._live_idx = np.arange(self.num_agents)
        self._chest_full[:] = True
        self._belief[:, : self.num_treasures] = 1.0
        self._t = 0
        self.treasures_collected = 0
        self._assigned[:] = -1
        if self.mode is Mode.deliberative:
            self._assign()
        self._obs[:] = 0.0
        self._write_obs(self._live_idx, self._pos, None, env_changed=True)
        return self._obs.copy()

    def step(self, actions: np.ndarray) -> StepOutcome:
        """Move every live agent at once; actions of non-live agents are ignored."""
        idx = self._live_idx
        if idx.size == 0:
            raise RuntimeError("the episode is over: call reset() before step()")
        acts = np.asarray(actions)[idx]
        if acts.min() < 0 or acts.max() >= self.num_actions:
            raise ValueError(f"actions must be in 0..{self.num_actions - 1}, got {acts.tolist()}")
        old = self._pos[idx]
        new = self._next[idx, old, acts]
        self._pos[idx] = new
        self._t += 1
        agents = self.num_agents
        bounced = np.zeros(agents, dtype=bool)
        bounced[idx] = self._bounce[old, acts]
        rewards = np.zeros(agents, dtype=np.float32)
        rewards[idx] = self.step_reward
        terminated = np.zeros(agents, dtype=bool)
        trap = np.zeros(agents, dtype=bool)
        kinds = self._kind[new]
        events = bool(kinds.any())
        collected = 0
        if events:
            collected = self._resolve_events(idx, new, kinds, rewards, terminated, trap)
        truncated = np.zeros(agents, dtype=bool)
        if self._t >= self.max_steps:
            truncated[idx] = ~terminated[idx]
        ended = terminated | truncated
        if ended.any():  # a chest is only ever emptied by an agent that thereby ends
            self._live &= ~ended
            self._live_idx = np.flatnonzero(self._live)
            if self.mode is Mode.deliberative and self._live_idx.size:
                self._assign()
        self._write_obs(idx, new, old, env_changed=events)
        if self.reward_mode is RewardMode.team:
            rewards[idx] = rewards[idx].sum()
        return StepOutcome(
            self._obs.copy(), rewards, terminated, truncated, trap, collected, self._live.copy(), bounced
        )

    def _resolve_events(
        self,
        idx: np.ndarray,
        new: np.ndarray,
        kinds: np.ndarray,
        rewards: np.ndarray,
        terminated: np.ndarray,
        trap: np.ndarray,
    ) -> int:
        """Slow path for the few steps where some agent entered a chest or a trap."""
        contenders: dict[int, list[int]] = {}
        hits = np.flatnonzero(kinds)
        for agent, cell, kind in zip(idx[hits].tolist(), new[hits].tolist(), kinds[hits].tolist()):
            if kind == _TRAP:
                rewards[agent] = self.trap_reward
                terminated[agent] = trap[agent] = True
            else:
                contenders.setdefault(int(self._chest_of[cell]), []).append(agent)
        collected = 0
        for chest, group in contenders.items():
            if self._chest_full[chest]:
                winner = group[int(self._rng.integers(len(group)))] if len(group) > 1 else group[0]
                self._chest_full[chest] = False
                rewards[winner] = self.treasure_reward
                terminated[winner] = True
                collected += 1
                if self.mode is not Mode.competitive:  # announced: everybody knows the truth
                    self._belief[:, chest] = 0.0
            self._belief[group, chest] = 0.0  # whoever entered saw it empty (or emptied it)
        self.treasures_collected += collected
        return collected

    def _assign(self) -> None:
        """Coordinator: live agents to full chests, minimum total shortest-path length."""
        live = self._live_idx
        full = np.flatnonzero(self._chest_full)
        self._assigned[live] = -1
        if live.size and full.size:
            cost = self._chest_dist[np.ix_(full, self._pos[live])].T
            picks = assign_agents(cost)
            self._assigned[live] = np.where(picks >= 0, full[picks], -1)

    def _write_obs(self, rows: np.ndarray, new: np.ndarray, old: np.ndarray | None, env_changed: bool) -> None:
        """Refresh the observation rows of the agents that just moved (others keep their last)."""
        obs = self._obs
        if self.obs_encoding is ObsEncoding.onehot:
            if old is not None:
                obs[rows, old] = 0.0
            obs[rows, new] = 1.0
        else:
            obs[rows, 0:2] = self._coords[new]
        if env_changed:
            k = self.num_treasures
            if self.include_treasures:
                lo, hi = self._offsets["treasures"]
                obs[rows, lo:hi] = self._belief[rows, :k]
            if self.mode is Mode.deliberative:
                lo, hi = self._offsets["assignment"]
                obs[rows, lo:hi] = 0.0
                chosen = self._assigned[rows]
                has = chosen >= 0
                obs[rows[has], lo + chosen[has]] = 1.0
        if self.view_radius > 0:
            lo, hi = self._offsets["view"]
            mid = hi - self._view_chest.shape[1]
            obs[rows, lo:mid] = self._view_static[new]
            obs[rows, mid:hi] = self._belief[rows[:, None], self._view_chest[new]]

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
        status = (
            f"step {self._t}/{self.max_steps}  live agents: {self._live_idx.tolist()}  "
            f"full chests: {int(self._chest_full.sum())}/{self.num_treasures}"
        )
        return text_grid(self.map, self.positions, self._live, self._chest_full) + "\n" + status

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
            colour[r, c] = COLOURS["chest_full" if self._chest_full[chest] else "chest_empty"]
        img = np.repeat(np.repeat(colour, px, axis=0), px, axis=1)
        img[::px, :] = COLOURS["grid"]
        img[:, ::px] = COLOURS["grid"]
        pad = px // 4
        for agent in self._live_idx.tolist():
            r, c = divmod(int(self._pos[agent]), n)
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
