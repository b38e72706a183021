"""R treasure-hunt games stepped together: the rules of :mod:`dqn_transfer.envs.game` on arrays with a
leading replica axis (JaxMARL's functional style, numpy only).

Three pieces, all plain data and functions:

* :class:`BatchedMaps` -- what never changes during a run: R maps of one size (and one agent count and
  chest count), the rules (mode, rewards, observation options) and the per-map tables derived from
  them. Build it with :func:`batch_maps`; replicas may play different maps.
* :class:`BatchedState` -- a NamedTuple of arrays, leading axis R: positions, who is live, which chests
  are full, every agent's beliefs, the coordinator's assignment, step counts, episode sums and the
  current observations.
* :func:`reset` ``(maps, rngs) -> (state, obs)`` and :func:`step` ``(maps, state, actions, rngs) ->
  (state, BatchedOutcome)``. Neither changes its inputs; ``step`` returns a new state.

The rules are the one-game core's exactly (``tests/test_batched_core.py`` checks every array against
:class:`~dqn_transfer.envs.game.TreasureHuntGame` step by step). Randomness: the one-game core draws
only the winner of a chest that several agents enter on one step (``rng.integers(len(group))``, chests
in the order of their lowest-index contender); :func:`step` draws the same way from ``rngs[r]`` for
replica ``r`` only, so replica ``r`` with its own generator reproduces a one-game core reset with
that generator. The coordinator's assignment draws nothing (its ties go to the lower agent index).

One difference that only shows with rewards that are not integers: ``reward_mode="team"`` adds the
live agents' rewards one after another in agent order in float32; the one-game core's ``sum`` does the
same for fewer than 8 live agents, and numpy's pairwise grouping beyond that (so the last bit can
differ for 8+ live agents with fractional rewards; the default rewards are integers and exact).

The training loop steps its replicas' games through this core (:mod:`dqn_transfer.envs.game_batch`).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import NamedTuple

import numpy as np

from dqn_transfer.enums import Mode, ObsEncoding, RewardMode, check_enum
from dqn_transfer.envs.game import ACTION_MOVES, _check_int, _check_reward, assign_agents
from dqn_transfer.envs.maps import GridMap
from dqn_transfer.envs.settings import DEFAULTS

_FREE, _CHEST, _TRAP = 0, 1, 2
# Brute-force assignment enumerates every injective assignment; beyond this many (e.g. 8 live agents and
# 8 full chests: 40320) a replica falls back to the one-game core's assign_agents.
MAX_ENUMERATED_ASSIGNMENTS = 20_000


@dataclass(frozen=True, eq=False)
class BatchedMaps:
    """R maps of one size with the rules they are played by; ``cells = size * size``, ``K`` agents,
    ``k`` chests, ``W = 2 * view_radius + 1``. Arrays are read-only and indexed by replica first.

    ``maps``: the R :class:`GridMap` s. ``obstacle [R, cells] bool``. ``kind [R, cells] int8``: 0 free,
    1 chest, 2 trap. ``chest_of [R, cells] int64``: chest number of a cell, ``k`` where there is none.
    ``starts [R, K] int64``: start cell of each agent. ``bounce [R, cells, 4] bool``: the action from
    the cell runs into an obstacle. ``next_cell [R, K, cells, 4] int64``: where an agent lands from a
    cell with an action (off-grid: stays; obstacle: its own start).
    ``chest_dist [R, k, cells] int64``: BFS path length from each chest avoiding obstacles and traps
    (``K * cells`` where unreachable; deliberative mode only, else shape ``[R, k, 0]``).
    ``view_static [R, cells, 2 * W * W] float32``: the view's obstacle-or-outside and trap planes;
    ``view_chest [R, cells, W * W] int64``: the chest number of each window cell (``k``: none) --
    both ``[R, cells, 0]`` when ``view_radius == 0``. ``position_code [cells, P] float32``: the
    ``position`` segment of each cell. ``reset_assigned [R, K] int64``: the coordinator's assignment
    at the start of an episode (``-1``: none, and all ``-1`` outside deliberative mode).
    ``reset_obs [R, K, obs_dim] float32``: every agent's observation after a reset.
    """

    maps: tuple[GridMap, ...]
    size: int
    num_agents: int
    num_treasures: int
    mode: Mode
    reward_mode: RewardMode
    obs_encoding: ObsEncoding
    view_radius: int
    max_steps: int
    treasure_reward: float
    trap_reward: float
    step_reward: float
    include_treasures: bool
    auto_reset: bool
    layout: tuple[tuple[str, int], ...]
    obs_dim: int
    obstacle: np.ndarray
    kind: np.ndarray
    chest_of: np.ndarray
    starts: np.ndarray
    bounce: np.ndarray
    next_cell: np.ndarray
    chest_dist: np.ndarray
    view_static: np.ndarray
    view_chest: np.ndarray
    position_code: np.ndarray
    reset_assigned: np.ndarray
    reset_obs: np.ndarray

    @property
    def num_replicas(self) -> int:
        return len(self.maps)

    @property
    def num_actions(self) -> int:
        return len(ACTION_MOVES)

    def offsets(self) -> dict[str, tuple[int, int]]:
        """Each observation segment's ``(start, end)`` columns."""
        found, start = {}, 0
        for name, width in self.layout:
            found[name] = (start, start + width)
            start += width
        return found


class BatchedState(NamedTuple):
    """The state of R games (leading axis R; ``K`` agents, ``k`` chests).

    ``pos [R, K] int64``: each agent's cell ``row * size + col``. ``live [R, K] bool``: who acts next.
    ``chest_full [R, k] bool``. ``belief [R, K, k + 1] float32``: what each agent believes of each
    chest (1 full, 0 empty) plus a constant-0 column ``k`` (the view's "no chest").
    ``assigned [R, K] int64``: the coordinator's chest for each agent (``-1``: none; deliberative).
    ``t [R] int64``: joint steps taken this episode. ``treasures_collected [R] int64``: chests emptied
    this episode. ``episode_return [R, K] float32``: each agent's reward summed over the episode.
    ``obs [R, K, obs_dim] float32``: every agent's current observation (a non-live agent's stays the
    one after its final move).
    """

    pos: np.ndarray
    live: np.ndarray
    chest_full: np.ndarray
    belief: np.ndarray
    assigned: np.ndarray
    t: np.ndarray
    treasures_collected: np.ndarray
    episode_return: np.ndarray
    obs: np.ndarray


class BatchedOutcome(NamedTuple):
    """What one joint step of R games did (a row of an agent that was not live is zero / False).

    ``obs [R, K, obs_dim] float32``: the observations to act on next -- with ``auto_reset``, a replica
    whose episode ended on this step has its reset observation here. ``final_obs [R, K, obs_dim]
    float32``: the observations right after the step, before any reset (the same array as ``obs``
    when no replica was reset). ``rewards [R, K] float32``. ``terminated [R, K] bool``: ended in a
    chest or a trap. ``truncated [R, K] bool``: still live at ``max_steps``. ``trap [R, K] bool``.
    ``bounced [R, K] bool``: moved into an obstacle, and so back to its own start.
    ``live [R, K] bool``: live after the step (before any reset). ``treasures_collected [R] int64``:
    chests emptied by this step. ``episode_end [R] bool``: no agent is live any more (these replicas
    were reset if ``auto_reset``). ``episode_return [R, K] float32``: the episode's sums up to and
    including this step (for a replica that was reset: of the finished episode).
    """

    obs: np.ndarray
    final_obs: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    trap: np.ndarray
    bounced: np.ndarray
    live: np.ndarray
    treasures_collected: np.ndarray
    episode_end: np.ndarray
    episode_return: np.ndarray


# ---------------------------------------------------------------------------------------- building
def batch_maps(
    grid_maps: Sequence[GridMap],
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
    auto_reset: bool = False,
) -> BatchedMaps:
    """The R games of ``grid_maps`` (one replica each, repeats allowed) under one set of rules, with
    the arguments of :class:`~dqn_transfer.envs.game.TreasureHuntGame`; ``auto_reset``: :func:`step`
    resets a replica whose episode ends. The maps must share their size, agent count and chest count
    (``ValueError`` otherwise)."""
    grid_maps = tuple(grid_maps)
    if not grid_maps:
        raise ValueError("batch_maps needs at least one map")
    shapes = sorted({(m.size, m.num_agents, m.num_treasures) for m in grid_maps})
    if len(shapes) > 1:
        named = "; ".join(f"size {n}, {a} agents, {k} chests" for n, a, k in shapes)
        raise ValueError(f"the maps of one batch must share their size, agent count and chest count; got {named}")
    n, map_agents, k = shapes[0]
    if num_agents is None:
        num_agents = map_agents
    elif isinstance(num_agents, bool) or not 1 <= num_agents <= map_agents:
        raise ValueError(f"num_agents must be between 1 and the maps' {map_agents} starts, got {num_agents!r}")
    mode = check_enum("mode", mode, Mode)
    obs_encoding = check_enum("obs_encoding", obs_encoding, ObsEncoding)
    view_radius = _check_int("view_radius", view_radius, 0)
    agents, cells, replicas = int(num_agents), n * n, len(grid_maps)

    def flat(cell: tuple[int, int]) -> int:
        return cell[0] * n + cell[1]

    obstacle = np.zeros((replicas, cells), dtype=bool)
    kind = np.full((replicas, cells), _FREE, dtype=np.int8)
    chest_of = np.full((replicas, cells), k, dtype=np.int64)
    starts = np.empty((replicas, agents), dtype=np.int64)
    for r, m in enumerate(grid_maps):
        obstacle[r, [flat(c) for c in m.obstacles]] = True
        kind[r, [flat(c) for c in m.traps]] = _TRAP
        kind[r, [flat(c) for c in m.chests]] = _CHEST
        chest_of[r, [flat(c) for c in m.chests]] = np.arange(k)
        starts[r] = [flat(c) for c in m.starts[:agents]]

    rows, cols = np.divmod(np.arange(cells), n)
    moves = np.empty((cells, len(ACTION_MOVES)), dtype=np.int64)
    for a, (dr, dc) in enumerate(ACTION_MOVES):
        rr, cc = rows + dr, cols + dc
        inside = (rr >= 0) & (rr < n) & (cc >= 0) & (cc < n)
        moves[:, a] = np.where(inside, rr * n + cc, np.arange(cells))
    bounce = obstacle[:, moves]  # [R, cells, 4]
    next_cell = np.where(bounce[:, None], starts[:, :, None, None], moves[None, None])

    if mode is Mode.deliberative:
        dist = np.stack([np.stack([m.distances_from(c).reshape(-1) for c in m.chests]) for m in grid_maps])
        chest_dist = np.where(dist < 0, agents * cells, dist).astype(np.int64)
    else:
        chest_dist = np.zeros((replicas, k, 0), dtype=np.int64)

    w = 2 * view_radius + 1
    if view_radius > 0:
        span = np.arange(-view_radius, view_radius + 1)
        wr = (rows[:, None, None] + span[None, :, None]).repeat(w, axis=2).reshape(cells, -1)
        wc = (cols[:, None, None] + span[None, None, :]).repeat(w, axis=1).reshape(cells, -1)
        inside = (wr >= 0) & (wr < n) & (wc >= 0) & (wc < n)
        idx = np.where(inside, np.clip(wr, 0, n - 1) * n + np.clip(wc, 0, n - 1), 0)  # [cells, W*W]
        blocked = np.where(inside[None], obstacle[:, idx], True)
        trapped = inside[None] & (kind[:, idx] == _TRAP)
        view_static = np.concatenate([blocked, trapped], axis=2).astype(np.float32)
        view_chest = np.where(inside[None], chest_of[:, idx], k)
    else:
        view_static = np.zeros((replicas, cells, 0), dtype=np.float32)
        view_chest = np.zeros((replicas, cells, 0), dtype=np.int64)

    if obs_encoding is ObsEncoding.onehot:
        position_code: np.ndarray = np.eye(cells, dtype=np.float32)
    else:
        position_code = np.stack([rows, cols], axis=1).astype(np.float32) / (n - 1)
    layout = [("position", position_code.shape[1])]
    if include_treasures:
        layout.append(("treasures", k))
    if mode is Mode.deliberative:
        layout.append(("assignment", k))
    if view_radius > 0:
        layout.append(("view", 3 * w * w))

    maps = BatchedMaps(
        maps=grid_maps,
        size=n,
        num_agents=agents,
        num_treasures=k,
        mode=mode,
        reward_mode=check_enum("reward_mode", reward_mode, RewardMode),
        obs_encoding=obs_encoding,
        view_radius=view_radius,
        max_steps=n * n if max_steps is None else _check_int("max_steps", max_steps, 1),
        treasure_reward=_check_reward("treasure_reward", treasure_reward),
        trap_reward=_check_reward("trap_reward", trap_reward),
        step_reward=_check_reward("step_reward", step_reward),
        include_treasures=bool(include_treasures),
        auto_reset=bool(auto_reset),
        layout=tuple(layout),
        obs_dim=sum(width for _, width in layout),
        obstacle=obstacle,
        kind=kind,
        chest_of=chest_of,
        starts=starts,
        bounce=bounce,
        next_cell=next_cell,
        chest_dist=chest_dist,
        view_static=view_static,
        view_chest=view_chest,
        position_code=position_code,
        reset_assigned=np.full((replicas, agents), -1, dtype=np.int64),
        reset_obs=np.zeros((replicas, agents, 0), dtype=np.float32),
    )
    fresh = _fresh_state(maps, np.arange(replicas))
    if mode is Mode.deliberative:  # every agent on its start, every chest full: the same each episode
        _reassign(maps, fresh.pos, fresh.live, fresh.chest_full, fresh.assigned, np.arange(replicas))
    obs = _observe(maps, fresh.pos, fresh.belief, fresh.assigned)
    object.__setattr__(maps, "reset_assigned", fresh.assigned)
    object.__setattr__(maps, "reset_obs", obs)
    for name in ("obstacle", "kind", "chest_of", "starts", "bounce", "next_cell", "chest_dist", "view_static"):
        getattr(maps, name).flags.writeable = False
    for array in (maps.view_chest, maps.position_code, maps.reset_assigned, maps.reset_obs):
        array.flags.writeable = False
    return maps


def _fresh_state(maps: BatchedMaps, replicas: np.ndarray) -> BatchedState:
    """Episode-start arrays of ``replicas`` (observations left empty)."""
    count, agents, k = len(replicas), maps.num_agents, maps.num_treasures
    belief = np.ones((count, agents, k + 1), dtype=np.float32)
    belief[:, :, k] = 0.0
    return BatchedState(
        pos=maps.starts[replicas].copy(),
        live=np.ones((count, agents), dtype=bool),
        chest_full=np.ones((count, k), dtype=bool),
        belief=belief,
        assigned=maps.reset_assigned[replicas].copy(),
        t=np.zeros(count, dtype=np.int64),
        treasures_collected=np.zeros(count, dtype=np.int64),
        episode_return=np.zeros((count, agents), dtype=np.float32),
        obs=maps.reset_obs[replicas].copy(),
    )


# ---------------------------------------------------------------------------------------- dynamics
def reset(maps: BatchedMaps, rngs: Sequence[np.random.Generator] | None = None) -> tuple[BatchedState, np.ndarray]:
    """Every replica at the start of an episode: ``(state, obs [R, K, obs_dim] float32)``.

    ``rngs`` is accepted for symmetry with :func:`step` (which draws the ties from it); a reset draws
    nothing."""
    del rngs
    state = _fresh_state(maps, np.arange(maps.num_replicas))
    return state, state.obs


def reset_where(maps: BatchedMaps, state: BatchedState, which: np.ndarray) -> BatchedState:
    """``state`` with the replicas of the mask ``which [R] bool`` at the start of a new episode (a new
    state; ``state`` is not changed). Their observations are ``result.obs[which]``."""
    replicas = np.flatnonzero(which)
    if replicas.size == 0:
        return state
    arrays = []
    for now, start in zip(state, _fresh_state(maps, replicas)):
        now = now.copy()
        now[replicas] = start
        arrays.append(now)
    return BatchedState(*arrays)


def step(
    maps: BatchedMaps,
    state: BatchedState,
    actions: np.ndarray,
    rngs: Sequence[np.random.Generator],
    finished_stay: bool = False,
) -> tuple[BatchedState, BatchedOutcome]:
    """One joint step of every replica: ``actions [R, K]`` integers in ``0..3`` (those of non-live
    agents are ignored); ``rngs[r]`` draws replica ``r``'s chest ties. Returns the new state and the
    :class:`BatchedOutcome`; the inputs are not changed.

    Without ``maps.auto_reset``, stepping a replica with no live agent is a ``RuntimeError`` (reset
    it first), unless ``finished_stay``: then such a replica stays as it is (a batch of episodes played
    to their ends, e.g. an evaluation's); with ``auto_reset``, such replicas never exist between steps."""
    replicas, agents, k = maps.num_replicas, maps.num_agents, maps.num_treasures
    live = state.live
    acts = np.asarray(actions)
    if acts.shape != (replicas, agents):
        raise ValueError(f"actions must have shape {(replicas, agents)}, got {acts.shape}")
    over = np.flatnonzero(~live.any(axis=1))
    if over.size and not finished_stay:
        raise RuntimeError(f"the episode is over in replicas {over.tolist()}: reset before stepping them")
    if acts.dtype.kind not in "iu":
        raise ValueError(f"actions must be integers, got dtype {acts.dtype}")
    played = acts[live]
    if played.size and (played.min() < 0 or played.max() >= maps.num_actions):
        raise ValueError(f"actions must be in 0..{maps.num_actions - 1}, got {np.unique(played).tolist()}")

    r_idx = np.arange(replicas)[:, None]
    a_idx = np.arange(agents)[None, :]
    chosen = np.where(live, acts, 0)
    moved = maps.next_cell[r_idx, a_idx, state.pos, chosen]
    pos = np.where(live, moved, state.pos)
    bounced = live & maps.bounce[r_idx, state.pos, chosen]
    kinds = np.where(live, maps.kind[r_idx, pos], _FREE)
    rewards = np.where(live, np.float32(maps.step_reward), np.float32(0.0)).astype(np.float32)
    trap = kinds == _TRAP
    rewards[trap] = maps.trap_reward

    chest_full = state.chest_full.copy()
    belief = state.belief.copy()
    on_chest = kinds == _CHEST
    chest = maps.chest_of[r_idx, pos]  # k where no chest
    won = np.zeros((replicas, agents), dtype=bool)
    if on_chest.any():
        # Contenders for a full chest: one wins outright, several draw a winner.
        entering_full = on_chest & chest_full[r_idx, np.minimum(chest, k - 1)] & (chest < k)
        slot = r_idx * k + chest
        counts = np.bincount(slot[entering_full], minlength=replicas * k).reshape(replicas, k)
        contenders = np.where(entering_full, counts[r_idx, np.minimum(chest, k - 1)], 0)
        won = contenders == 1
        for r in np.flatnonzero((contenders > 1).any(axis=1)).tolist():
            groups: dict[int, list[int]] = {}
            for a in np.flatnonzero(entering_full[r]).tolist():
                groups.setdefault(int(chest[r, a]), []).append(a)
            for group in groups.values():
                if len(group) > 1:
                    won[r, group[int(rngs[r].integers(len(group)))]] = True
        wr, wa = np.nonzero(won)
        emptied = chest[wr, wa]
        chest_full[wr, emptied] = False
        if maps.mode is not Mode.competitive:  # announced: everybody knows the truth
            belief[wr, :, emptied] = 0.0
        cr, ca = np.nonzero(on_chest)
        belief[cr, ca, chest[cr, ca]] = 0.0  # whoever entered saw it empty (or emptied it)
        rewards[won] = maps.treasure_reward
    terminated = trap | won
    collected = won.sum(axis=1)

    t = state.t + live.any(axis=1)  # a finished replica's clock stays
    truncated = live & ~terminated & (t >= maps.max_steps)[:, None]
    now_live = live & ~(terminated | truncated)
    assigned = state.assigned
    if maps.mode is Mode.deliberative:
        again = np.flatnonzero(terminated.any(axis=1) & now_live.any(axis=1))
        if again.size:
            assigned = assigned.copy()
            _reassign(maps, pos, now_live, chest_full, assigned, again)
    if maps.reward_mode is RewardMode.team:
        total = np.zeros(replicas, dtype=np.float32)
        for a in range(agents):  # in agent order, in float32, as the one-game core's sum
            total = np.where(live[:, a], total + rewards[:, a], total)
        rewards = np.where(live, total[:, None], np.float32(0.0)).astype(np.float32)
    obs = np.where(live[:, :, None], _observe(maps, pos, belief, assigned), state.obs)
    episode_return = state.episode_return + rewards
    treasures = state.treasures_collected + collected
    new = BatchedState(pos, now_live, chest_full, belief, assigned, t, treasures, episode_return, obs)
    ended = ~now_live.any(axis=1)
    next_obs = obs
    if maps.auto_reset and ended.any():
        new = reset_where(maps, new, ended)
        next_obs = new.obs
    outcome = BatchedOutcome(
        obs=next_obs,
        final_obs=obs,
        rewards=rewards,
        terminated=terminated,
        truncated=truncated,
        trap=trap,
        bounced=bounced,
        live=now_live,
        treasures_collected=collected,
        episode_end=ended,
        episode_return=episode_return,
    )
    return new, outcome


def _observe(maps: BatchedMaps, pos: np.ndarray, belief: np.ndarray, assigned: np.ndarray) -> np.ndarray:
    """Every agent's observation ``[R, K, obs_dim]`` float32 from its cell, beliefs and assignment."""
    (replicas, agents), k = pos.shape, maps.num_treasures
    parts = [maps.position_code[pos]]
    if maps.include_treasures:
        parts.append(belief[:, :, :k])
    if maps.mode is Mode.deliberative:
        onehot = np.zeros((replicas, agents, k + 1), dtype=np.float32)
        np.put_along_axis(onehot, np.where(assigned >= 0, assigned, k)[:, :, None], 1.0, axis=2)
        parts.append(onehot[:, :, :k])
    if maps.view_radius > 0:
        r_idx = np.arange(replicas)[:, None]
        parts.append(maps.view_static[r_idx, pos])
        window = maps.view_chest[r_idx, pos]  # [R, K, W*W]
        parts.append(np.take_along_axis(belief, window, axis=2))
    return np.concatenate(parts, axis=2)


# ------------------------------------------------------------------------------------ the coordinator
def _reassign(
    maps: BatchedMaps,
    pos: np.ndarray,
    live: np.ndarray,
    chest_full: np.ndarray,
    assigned: np.ndarray,
    replicas: np.ndarray,
) -> None:
    """The coordinator of ``replicas``, in place on ``assigned``: live agents to full chests for the
    least total path length, ties as :func:`~dqn_transfer.envs.game.assign_agents` breaks them (agents
    that are not live keep their last assignment). Replicas with the same numbers of live agents and
    full chests are solved together by enumerating the assignments."""
    assigned[replicas] = np.where(live[replicas], -1, assigned[replicas])
    num_live, num_full = live[replicas].sum(axis=1), chest_full[replicas].sum(axis=1)
    for size_l, size_f in sorted(set(zip(num_live.tolist(), num_full.tolist()))):
        if size_l == 0 or size_f == 0:
            continue
        group = replicas[(num_live == size_l) & (num_full == size_f)]
        agent_idx = np.nonzero(live[group])[1].reshape(len(group), size_l)
        full_idx = np.nonzero(chest_full[group])[1].reshape(len(group), size_f)
        cells = pos[group[:, None], agent_idx]  # [G, L]
        cost = maps.chest_dist[group[:, None, None], full_idx[:, None, :], cells[:, :, None]]  # [G, L, F]
        picks = assign_batch(cost)
        chosen = np.take_along_axis(full_idx, np.maximum(picks, 0), axis=1)
        assigned[group[:, None], agent_idx] = np.where(picks >= 0, chosen, -1)


@cache
def injections(num_rows: int, num_cols: int) -> np.ndarray:
    """Every assignment of ``min(num_rows, num_cols)`` rows to distinct columns: ``[P, num_rows]``
    int64, the column of each row or ``-1`` (only when there are more rows than columns)."""
    if num_rows <= num_cols:
        table = np.array(list(itertools.permutations(range(num_cols), num_rows)), dtype=np.int64)
        return table.reshape(-1, num_rows)
    found = []
    for rows in itertools.permutations(range(num_rows), num_cols):
        row = np.full(num_rows, -1, dtype=np.int64)
        row[list(rows)] = np.arange(num_cols)
        found.append(row)
    return np.array(found, dtype=np.int64)


def _count_injections(num_rows: int, num_cols: int) -> int:
    high, low = max(num_rows, num_cols), min(num_rows, num_cols)
    count = 1
    for factor in range(high - low + 1, high + 1):
        count *= factor
    return count


def assign_batch(cost: np.ndarray) -> np.ndarray:
    """:func:`~dqn_transfer.envs.game.assign_agents` of each of G integer cost matrices ``[G, L, F]``:
    ``[G, L]`` int64 chest columns (``-1``: none).

    Among the assignments of ``min(L, F)`` pairs with the least total cost, the one whose agents, in
    index order, get their most preferred options (cheapest chest, then lowest column, then none) --
    the lexicographic minimum of the options' ranks, which is what ``assign_agents``' greedy fixing
    picks. Done by enumerating all assignments; too many of them, and each matrix goes to
    ``assign_agents`` instead."""
    groups, num_rows, num_cols = cost.shape
    base = num_cols + 1
    if _count_injections(num_rows, num_cols) > MAX_ENUMERATED_ASSIGNMENTS or base**num_rows >= 2**62:
        return np.stack([assign_agents(matrix) for matrix in cost]).reshape(groups, num_rows)
    table = injections(num_rows, num_cols)
    column = np.where(table >= 0, table, num_cols)  # [P, L], num_cols = none
    padded = np.concatenate([cost, np.zeros((groups, num_rows, 1), dtype=cost.dtype)], axis=2)
    rows = np.arange(num_rows)[None, :]
    totals = padded[:, rows, column].sum(axis=2)  # [G, P]
    order = np.argsort(cost, axis=2, kind="stable")  # preference: cost, then column
    rank = np.empty((groups, num_rows, base), dtype=np.int64)
    np.put_along_axis(rank, order, np.arange(num_cols)[None, None, :], axis=2)
    rank[:, :, num_cols] = num_cols  # no chest: after every chest
    weights = base ** np.arange(num_rows - 1, -1, -1, dtype=np.int64)
    codes = (rank[:, rows, column] * weights).sum(axis=2)  # [G, P]: lexicographic order of the ranks
    codes = np.where(totals == totals.min(axis=1, keepdims=True), codes, np.iinfo(np.int64).max)
    return table[np.argmin(codes, axis=1)]
