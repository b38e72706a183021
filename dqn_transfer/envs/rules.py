"""The treasure hunt's rules, stated once: plain loops compiled by numba over R replicas of the game.

Every game of the package is stepped here: one game is R = 1 (:class:`~dqn_transfer.envs.game.TreasureHuntGame`,
behind the PettingZoo and Gymnasium faces), a run's replicas and an evaluation's episodes are R games
stepped together (:class:`~dqn_transfer.envs.game.TreasureHunts`). The state is plain arrays with a
leading replica axis (JaxMARL's style); :class:`Tables` is what never changes during a run.

A joint step of replica r, agent by agent in index order (:func:`step`):

1. every live agent moves: off the grid it stays, into an obstacle it goes back to its own start;
   each pays ``step_reward``; an agent entering a trap gets ``trap_reward`` and ends;
2. agents entering a full chest contend for it: a lone one takes it, several draw the winner from the
   replica's generator (the only draw of the game: chests in the order of their lowest-index contender,
   ``rng.integers(contenders)``, drawn in the kernel from the generator's packed state,
   :mod:`~dqn_transfer.envs.tie_draws`);
   the winner gets ``treasure_reward`` and ends, the others pay the step and play on. Whoever entered a
   chest now believes it empty; outside ``competitive`` mode an emptied chest is announced to all;
3. agents still live at ``max_steps`` are truncated; in ``deliberative`` mode the coordinator assigns
   the live agents to the full chests again when an agent has ended (:func:`assign`);
4. with ``reward_mode="team"``, every agent that acted gets the sum of the step's rewards (added in
   agent order in float32); the observations of the agents that acted are written (:func:`observe`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

import dqn_transfer.envs.tie_draws as tie_draws
from dqn_transfer.compiled import kernel
from dqn_transfer.enums import Mode, ObsEncoding
from dqn_transfer.envs.maps import GridMap

ACTION_MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # 0 up, 1 down, 2 left, 3 right
FREE, CHEST, TRAP = 0, 1, 2  # what a cell holds, besides obstacles
NO_CHEST = -1  # ``entered``: the agent did not enter a chest
# Step status (what :func:`step` returns).
DONE, TIES_DRAWN, BAD_ACTION = 0, 1, 2


class Tables(NamedTuple):
    """What never changes during a run: R maps of one size (``cells = size * size``, ``K`` agents,
    ``k`` chests, view window ``W = 2 * view_radius + 1``), indexed by replica first.

    ``next_cell [R, K, cells, 4] int64``: where an agent lands from a cell with an action (off-grid:
    stays; obstacle: its own start). ``bounce [R, cells, 4] bool``: the action runs into an obstacle.
    ``kind [R, cells] int8``: FREE, CHEST or TRAP. ``chest_of [R, cells] int64``: a cell's chest number
    (``k``: none). ``starts [R, K] int64``. ``chest_dist [R, k, cells] int64``: shortest path length from
    each chest avoiding obstacles and traps, ``K * cells`` where unreachable (deliberative mode only, else
    ``[R, k, 0]``). ``position_code [cells, P] float32``: the ``position`` segment of each cell.
    ``view_static [R, cells, 2 W W] float32``: the view's obstacle-or-outside and trap planes;
    ``view_chest [R, cells, W W] int64``: the chest number of each window cell (``k``: none); both
    ``[R, cells, 0]`` without a view. ``segments int64 [3]``: the first column of the ``treasures``,
    ``assignment`` and ``view`` segments (``-1``: absent).
    """

    next_cell: np.ndarray
    bounce: np.ndarray
    kind: np.ndarray
    chest_of: np.ndarray
    starts: np.ndarray
    chest_dist: np.ndarray
    position_code: np.ndarray
    view_static: np.ndarray
    view_chest: np.ndarray
    segments: np.ndarray


def obs_layout(
    size: int, num_treasures: int, mode: Mode, obs_encoding: ObsEncoding, view_radius: int, include_treasures: bool
) -> list[tuple[str, int]]:
    """The observation's named segments, in order."""
    layout = [("position", size * size if obs_encoding is ObsEncoding.onehot else 2)]
    if include_treasures:
        layout.append(("treasures", num_treasures))
    if mode is Mode.deliberative:
        layout.append(("assignment", num_treasures))
    if view_radius > 0:
        layout.append(("view", 3 * (2 * view_radius + 1) ** 2))
    return layout


def position_codes(size: int, obs_encoding: ObsEncoding) -> np.ndarray:
    """The ``position`` segment of each cell, row-major: ``[size * size, P]`` float32."""
    if obs_encoding is ObsEncoding.onehot:
        return np.eye(size * size, dtype=np.float32)
    rows, cols = np.divmod(np.arange(size * size), size)
    return np.stack([rows, cols], axis=1).astype(np.float32) / (size - 1)


def build_tables(
    grid_maps: Sequence[GridMap],
    num_agents: int,
    mode: Mode,
    obs_encoding: ObsEncoding,
    view_radius: int,
    layout: Sequence[tuple[str, int]],
) -> Tables:
    """The :class:`Tables` of ``grid_maps`` (one per replica; one size, at least ``num_agents`` starts and
    the same chest count) for the first ``num_agents`` agents. Each distinct map's tables are computed
    once (an evaluation's R x E games are R maps)."""
    first_of: dict[str, int] = {}
    which = np.array([first_of.setdefault(m.layout, len(first_of)) for m in grid_maps])
    if len(first_of) < len(grid_maps):
        distinct = [grid_maps[int(np.argmax(which == d))] for d in range(len(first_of))]
        tables = build_tables(distinct, num_agents, mode, obs_encoding, view_radius, layout)
        shared = {"position_code", "segments"}
        gathered = Tables(*(a if name in shared else a[which] for name, a in zip(Tables._fields, tables)))
        for array in gathered:
            array.flags.writeable = False
        return gathered
    n, k, replicas = grid_maps[0].size, grid_maps[0].num_treasures, len(grid_maps)
    cells = n * n
    obstacle = np.zeros((replicas, cells), dtype=bool)
    kind = np.full((replicas, cells), FREE, dtype=np.int8)
    chest_of = np.full((replicas, cells), k, dtype=np.int64)
    starts = np.empty((replicas, num_agents), dtype=np.int64)
    for r, m in enumerate(grid_maps):
        flat = [[row * n + col for row, col in cells_of] for cells_of in (m.obstacles, m.traps, m.chests)]
        obstacle[r, flat[0]] = True
        kind[r, flat[1]] = TRAP
        kind[r, flat[2]] = CHEST
        chest_of[r, flat[2]] = np.arange(k)
        starts[r] = [row * n + col for row, col in m.starts[:num_agents]]

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
        chest_dist = np.where(dist < 0, num_agents * cells, dist).astype(np.int64)
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
        trapped = inside[None] & (kind[:, idx] == TRAP)
        view_static = np.concatenate([blocked, trapped], axis=2).astype(np.float32)
        view_chest = np.where(inside[None], chest_of[:, idx], k)
    else:
        view_static = np.zeros((replicas, cells, 0), dtype=np.float32)
        view_chest = np.zeros((replicas, cells, 0), dtype=np.int64)

    starts_of, column = {}, 0
    for name, width in layout:
        starts_of[name] = column
        column += width
    segments = np.array([starts_of.get(name, -1) for name in ("treasures", "assignment", "view")], dtype=np.int64)
    tables = Tables(
        next_cell=next_cell,
        bounce=bounce,
        kind=kind,
        chest_of=chest_of,
        starts=starts,
        chest_dist=chest_dist,
        position_code=position_codes(n, obs_encoding),
        view_static=view_static,
        view_chest=view_chest,
        segments=segments,
    )
    # C-contiguous whatever the indexing made them: one compiled version of each kernel serves every batch.
    tables = Tables(*(np.ascontiguousarray(array) for array in tables))
    for array in tables:
        array.flags.writeable = False
    return tables


class State(NamedTuple):
    """R games in progress (leading axis R; ``K`` agents, ``k`` chests), changed in place by the kernels.

    ``pos [R, K] int64``: each agent's cell ``row * size + col``. ``live [R, K] bool``: who acts next.
    ``chest_full [R, k] bool``. ``belief [R, K, k + 1] float32``: what each agent believes of each chest
    (1 full, 0 empty) and a constant-0 column ``k`` (the view's "no chest"). ``assigned [R, K] int64``:
    the coordinator's chest for each agent (``-1``: none; deliberative mode). ``t [R] int64``: joint
    steps of the episode. ``treasures_collected [R] int64``: chests emptied in the episode.
    ``obs [R, K, obs_dim] float32``: every agent's observation (a non-live agent's stays its last).
    ``tie_rng [R, 6] uint64``: each replica's generator of chest ties, packed
    (:func:`~dqn_transfer.envs.tie_draws.pack`); ``tie_drawn [R] bool``: it drew since it was last
    unpacked into the generator.
    """

    pos: np.ndarray
    live: np.ndarray
    chest_full: np.ndarray
    belief: np.ndarray
    assigned: np.ndarray
    t: np.ndarray
    treasures_collected: np.ndarray
    obs: np.ndarray
    tie_rng: np.ndarray
    tie_drawn: np.ndarray

    @staticmethod
    def empty(replicas: int, agents: int, chests: int, obs_dim: int) -> State:
        return State(
            pos=np.zeros((replicas, agents), dtype=np.int64),
            live=np.zeros((replicas, agents), dtype=bool),
            chest_full=np.zeros((replicas, chests), dtype=bool),
            belief=np.zeros((replicas, agents, chests + 1), dtype=np.float32),
            assigned=np.full((replicas, agents), -1, dtype=np.int64),
            t=np.zeros(replicas, dtype=np.int64),
            treasures_collected=np.zeros(replicas, dtype=np.int64),
            obs=np.zeros((replicas, agents, obs_dim), dtype=np.float32),
            tie_rng=np.zeros((replicas, tie_draws.WORDS), dtype=np.uint64),
            tie_drawn=np.zeros(replicas, dtype=bool),
        )


class Outcome(NamedTuple):
    """What one joint step did (a row of an agent that did not act is zero / False), filled by :func:`step`.

    ``rewards [R, K] float32``; ``terminated [R, K] bool``: ended in a chest or a trap; ``truncated
    [R, K] bool``: still live at ``max_steps``; ``trap [R, K] bool``; ``bounced [R, K] bool``: moved into
    an obstacle; ``acted [R, K] bool``: was live before the step; ``collected [R] int64``: chests
    emptied by the step; ``ended [R] bool``: no agent of the replica is live any more. The chests'
    contests: ``entered [R, K] int64``, the chest an agent entered (``-1``: none); ``contenders
    [R, k] int64``, how many agents entered each chest while it was full; ``winner [R, k] int64``,
    which of them (in agent order) takes it (``-1``: not drawn).
    """

    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    trap: np.ndarray
    bounced: np.ndarray
    acted: np.ndarray
    collected: np.ndarray
    ended: np.ndarray
    entered: np.ndarray
    contenders: np.ndarray
    winner: np.ndarray

    @staticmethod
    def empty(replicas: int, agents: int, chests: int) -> Outcome:
        def flags() -> np.ndarray:
            return np.zeros((replicas, agents), dtype=bool)

        return Outcome(
            rewards=np.zeros((replicas, agents), dtype=np.float32),
            terminated=flags(),
            truncated=flags(),
            trap=flags(),
            bounced=flags(),
            acted=flags(),
            collected=np.zeros(replicas, dtype=np.int64),
            ended=np.zeros(replicas, dtype=bool),
            entered=np.full((replicas, agents), NO_CHEST, dtype=np.int64),
            contenders=np.zeros((replicas, chests), dtype=np.int64),
            winner=np.zeros((replicas, chests), dtype=np.int64),
        )


# ---------------------------------------------------------------------------------------- the kernels
@kernel
def observe(tables, state, r, a):
    """Write agent ``a`` of replica ``r``'s observation from its cell, beliefs and assignment."""
    row = state.obs[r, a]
    cell = state.pos[r, a]
    code = tables.position_code[cell]
    for j in range(code.shape[0]):
        row[j] = code[j]
    k = state.chest_full.shape[1]
    treasures, assignment, view = tables.segments[0], tables.segments[1], tables.segments[2]
    if treasures >= 0:
        for c in range(k):
            row[treasures + c] = state.belief[r, a, c]
    if assignment >= 0:
        for c in range(k):
            row[assignment + c] = 0.0
        if state.assigned[r, a] >= 0:
            row[assignment + state.assigned[r, a]] = 1.0
    if view >= 0:
        static = tables.view_static[r, cell]
        for j in range(static.shape[0]):
            row[view + j] = static[j]
        window = tables.view_chest[r, cell]
        start = view + static.shape[0]
        for j in range(window.shape[0]):
            row[start + j] = state.belief[r, a, window[j]]


@kernel
def best_assignment(cost):
    """Chest column for each agent row of the integer ``cost [L, F]`` (``-1``: none), for the least total.

    Among the assignments of ``min(L, F)`` pairs of least total, the one whose agents, in index order,
    get their most preferred options (cheapest chest, then lowest column, then none: only with more agents
    than chests): a depth-first search that meets the assignments in that order of preference, pruned
    where even each remaining agent's cheapest chest cannot beat the best total found so far."""
    num_rows, num_cols = cost.shape
    none_left = max(num_rows - num_cols, 0)  # how many agents go without a chest
    options = num_cols + (1 if none_left > 0 else 0)
    order = np.empty((num_rows, num_cols), dtype=np.int64)  # each row's columns by cost, then column
    for i in range(num_rows):
        for j in range(num_cols):  # insertion sort: stable, and a few lines to compile (argsort's are seconds)
            at = j
            while at > 0 and cost[i, order[i, at - 1]] > cost[i, j]:
                order[i, at] = order[i, at - 1]
                at -= 1
            order[i, at] = j
    lower_bound = np.zeros(num_rows + 1, dtype=np.int64)  # the least cost rows i.. could still add
    for i in range(num_rows - 1, -1, -1):
        lower_bound[i] = lower_bound[i + 1] + (0 if none_left > 0 else cost[i, order[i, 0]])
    used = np.zeros(num_cols, dtype=np.bool_)
    choice = np.full(num_rows, -1, dtype=np.int64)  # option index tried at each depth
    column = np.full(num_rows, -1, dtype=np.int64)  # its column (-1: none)
    best = np.full(num_rows, -1, dtype=np.int64)
    best_total = np.iinfo(np.int64).max
    total, nones, depth = 0, 0, 0
    while depth >= 0:
        if choice[depth] >= 0:  # undo the option tried here before
            if column[depth] >= 0:
                used[column[depth]] = False
                total -= cost[depth, column[depth]]
            else:
                nones -= 1
        option = choice[depth] + 1
        while option < options and (
            (option < num_cols and used[order[depth, option]]) or (option == num_cols and nones == none_left)
        ):
            option += 1
        if option == options:  # every option tried: back up
            choice[depth] = -1
            depth -= 1
            continue
        choice[depth] = option
        if option < num_cols:
            column[depth] = order[depth, option]
            used[column[depth]] = True
            total += cost[depth, column[depth]]
        else:
            column[depth] = -1
            nones += 1
        if total + lower_bound[depth + 1] >= best_total:
            continue  # cannot beat (or is a later tie of) the best found
        if depth == num_rows - 1:
            best_total = total
            best[:] = column
        else:
            depth += 1
    return best


@kernel
def assign(tables, state, r):
    """The coordinator of replica ``r``: its live agents to its full chests, least total path length
    (:func:`best_assignment`); agents that are not live keep their last assignment."""
    agents, chests = state.live.shape[1], state.chest_full.shape[1]
    live = np.empty(agents, dtype=np.int64)
    full = np.empty(chests, dtype=np.int64)
    num_live, num_full = 0, 0
    for a in range(agents):
        if state.live[r, a]:
            live[num_live] = a
            num_live += 1
            state.assigned[r, a] = -1
    for c in range(chests):
        if state.chest_full[r, c]:
            full[num_full] = c
            num_full += 1
    if num_live == 0 or num_full == 0:
        return
    cost = np.empty((num_live, num_full), dtype=np.int64)
    for i in range(num_live):
        for j in range(num_full):
            cost[i, j] = tables.chest_dist[r, full[j], state.pos[r, live[i]]]
    picks = best_assignment(cost)
    for i in range(num_live):
        if picks[i] >= 0:
            state.assigned[r, live[i]] = full[picks[i]]


@kernel
def reset_replica(tables, state, r):
    """Start a new episode in replica ``r``: agents on their starts, every chest full and believed so,
    the coordinator's assignment (deliberative) and the observations."""
    agents, chests = state.live.shape[1], state.chest_full.shape[1]
    for a in range(agents):
        state.pos[r, a] = tables.starts[r, a]
        state.live[r, a] = True
        state.assigned[r, a] = -1
        for c in range(chests):
            state.belief[r, a, c] = 1.0
        state.belief[r, a, chests] = 0.0
    for c in range(chests):
        state.chest_full[r, c] = True
    state.t[r] = 0
    state.treasures_collected[r] = 0
    if tables.chest_dist.shape[2] > 0:  # deliberative
        assign(tables, state, r)
    for a in range(agents):
        state.obs[r, a] = 0.0
        observe(tables, state, r, a)


@kernel
def reset(tables, state, which):
    """:func:`reset_replica` of the replicas of the mask ``which [R]``."""
    for r in range(state.pos.shape[0]):
        if which[r]:
            reset_replica(tables, state, r)


@kernel
def step(tables, state, actions, out, rewards, max_steps, team, announce):
    """One joint step of every replica (the module docstring's rules), in place on ``state`` and ``out``.

    ``actions [R, K]`` (those of non-live agents are ignored); ``rewards`` (step, trap, treasure) as
    float32; ``team``: team rewards; ``announce``: an emptied chest is announced to all (not
    competitive). Returns BAD_ACTION (nothing changed but the contests' scratch) if a live agent's
    action is not in 0..3, else TIES_DRAWN if a replica drew a chest's winner (``state.tie_drawn``),
    else DONE.
    """
    replicas, agents = state.pos.shape
    chests = state.chest_full.shape[1]
    step_reward, trap_reward, treasure_reward = rewards[0], rewards[1], rewards[2]
    for r in range(replicas):
        for c in range(chests):
            out.contenders[r, c] = 0
            out.winner[r, c] = -1
        for a in range(agents):
            out.entered[r, a] = NO_CHEST
            if not state.live[r, a]:
                continue
            action = actions[r, a]
            if action < 0 or action > 3:
                return BAD_ACTION
            landing = tables.next_cell[r, a, state.pos[r, a], action]
            if tables.kind[r, landing] == CHEST:
                c = tables.chest_of[r, landing]
                out.entered[r, a] = c
                if state.chest_full[r, c]:
                    out.contenders[r, c] += 1
    # The contested chests' winners, in the order of their lowest-index contender.
    status = DONE
    for r in range(replicas):
        for a in range(agents):
            c = out.entered[r, a]
            if c != NO_CHEST and out.contenders[r, c] > 1 and out.winner[r, c] < 0:
                out.winner[r, c] = tie_draws.integers(state.tie_rng[r], out.contenders[r, c])
                state.tie_drawn[r] = True
                status = TIES_DRAWN

    for r in range(replicas):
        out.collected[r] = 0
        any_live = False
        for a in range(agents):
            out.acted[r, a] = state.live[r, a]
            any_live = any_live or state.live[r, a]
            out.rewards[r, a] = 0.0
            out.terminated[r, a] = False
            out.truncated[r, a] = False
            out.trap[r, a] = False
            out.bounced[r, a] = False
        out.ended[r] = not any_live
        if not any_live:
            continue  # a finished episode stays as it is (its clock too)
        state.t[r] += 1
        # 1. moves, traps
        for a in range(agents):
            if not state.live[r, a]:
                continue
            cell, action = state.pos[r, a], actions[r, a]
            out.bounced[r, a] = tables.bounce[r, cell, action]
            landing = tables.next_cell[r, a, cell, action]
            state.pos[r, a] = landing
            out.rewards[r, a] = step_reward
            if tables.kind[r, landing] == TRAP:
                out.rewards[r, a] = trap_reward
                out.terminated[r, a] = True
                out.trap[r, a] = True
        # 2. chests: the contenders of each full chest, in agent order, and the winner among them
        met = np.zeros(chests, dtype=np.int64)
        for a in range(agents):
            c = out.entered[r, a]
            if c == NO_CHEST:
                continue
            if out.contenders[r, c] > 0:  # the chest was full when the step began
                if met[c] == (out.winner[r, c] if out.contenders[r, c] > 1 else 0):
                    out.rewards[r, a] = treasure_reward
                    out.terminated[r, a] = True
                    out.collected[r] += 1
                    state.chest_full[r, c] = False
                    if announce:
                        for b in range(agents):
                            state.belief[r, b, c] = 0.0
                met[c] += 1
            state.belief[r, a, c] = 0.0  # whoever entered saw it empty (or emptied it)
        state.treasures_collected[r] += out.collected[r]
        # 3. time limit, who is still live, the coordinator
        someone_ended, someone_live = False, False
        for a in range(agents):
            if not state.live[r, a]:
                continue
            if not out.terminated[r, a] and state.t[r] >= max_steps:
                out.truncated[r, a] = True
            if out.terminated[r, a] or out.truncated[r, a]:
                state.live[r, a] = False
                someone_ended = someone_ended or out.terminated[r, a]
            else:
                someone_live = True
        out.ended[r] = not someone_live
        if someone_ended and someone_live and tables.chest_dist.shape[2] > 0:
            assign(tables, state, r)
        # 4. team rewards, observations
        if team:
            total = np.float32(0.0)
            for a in range(agents):
                if out.acted[r, a]:
                    total += out.rewards[r, a]
            for a in range(agents):
                if out.acted[r, a]:
                    out.rewards[r, a] = total
        for a in range(agents):
            if out.acted[r, a]:
                observe(tables, state, r, a)
    return status


@kernel
def team_step_return(out, r, team):
    """Replica ``r``'s team return of the step ``out`` records, as an episode's sums count it: the float32
    sum of the rewards of the agents that acted, in agent order (with ``team`` rewards, their shared
    reward, counted once), as float64; 0.0 when no agent acted."""
    total = np.float32(0.0)
    best = np.float32(-np.inf)
    acted = False
    for a in range(out.rewards.shape[1]):
        if out.acted[r, a]:
            acted = True
            total += out.rewards[r, a]
            best = max(best, out.rewards[r, a])
        else:
            total += np.float32(0.0)  # as numpy's sum of the masked row: -0.0 + 0.0 is 0.0
    if not acted:
        return 0.0
    return np.float64(best) if team else np.float64(total)


# numba unboxes plain array arguments about twice as fast as NamedTuples of them (2.9 against 5.7 us a
# step of one game): the game passes its tables, state and outcome as one row of arrays to these.
TABLES_END = len(Tables._fields)  # where a row's State begins, and where its Outcome begins:
STATE_END = TABLES_END + len(State._fields)


def arrays(tables: Tables, state: State, out: Outcome) -> tuple[np.ndarray, ...]:
    """The row of arrays :func:`step_arrays` and :func:`reset_arrays` take."""
    return (*tables, *state, *out)


@kernel
def step_arrays(actions, rewards, max_steps, team, announce, *row):
    """:func:`step` on the :func:`arrays` of a Tables, a State and an Outcome."""
    tables = Tables(*row[:TABLES_END])
    state = State(*row[TABLES_END:STATE_END])
    out = Outcome(*row[STATE_END:])
    return step(tables, state, actions, out, rewards, max_steps, team, announce)


@kernel
def reset_arrays(which, *row):
    """:func:`reset` on the :func:`arrays` of a Tables, a State and an Outcome."""
    reset(Tables(*row[:TABLES_END]), State(*row[TABLES_END:STATE_END]), which)
