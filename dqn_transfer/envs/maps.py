"""Treasure-hunt maps: generation, parsing and validation.

A map is an ``n x n`` ASCII grid, one row per line, with the legend

    ``.`` free    ``#`` obstacle    ``T`` treasure chest    ``X`` trap    ``0``-``9`` agent start

Every map, generated or given, obeys the same rules:

1. the non-obstacle cells (free, chests, traps, starts) are 4-connected: no closed area;
2. no trap is in the 8-neighbourhood of a chest ("not right beside");
3. every chest is reachable from every start through cells that are neither obstacles nor traps;
4. start digits are ``0..m-1`` without gaps or duplicates, and there is at least one chest.

Cells are named ``row r, col c`` counting from 0, top-left first: the same convention as the
``position`` observation index ``r * n + c``.
"""

from __future__ import annotations

import functools
import warnings
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dqn_transfer.enums import Contention, check_enum
from dqn_transfer.envs.settings import DEFAULTS

Cell = tuple[int, int]

FREE, OBSTACLE, CHEST, TRAP = ".", "#", "T", "X"
LEGEND = frozenset(FREE + OBSTACLE + CHEST + TRAP + "0123456789")
MAX_AGENTS = 10  # one start digit per agent

# Bounded retries of generate_layout: at least this many obstacle layouts, and object placements
# per layout; small maps (cheap attempts, tight fits) get more, about _WORK_BUDGET / cells.
_MIN_OBSTACLE_ATTEMPTS = 3
_MIN_OBJECT_ATTEMPTS = 10
_WORK_BUDGET = 2000
# A contention other than `any` takes the first of a map seed's candidate draws that meets it; at most
# this many are drawn before the request is refused. The rarest of the study's (6 agents on 10x10, low)
# is 0.8% of candidates: 1,000 would miss about one seed in 3,000, 4,000 one in 10^14.
CONTENTION_CANDIDATES = 4000
# contention=high: every agent shares its nearest chest. A laxer rule (half of them) holds on 80-95% of the
# maps `any` gives teams of 3 to 6 on 10x10 (docs/game.md), so it would hardly differ from `any`.
HIGH_CONTENTION = 1.0

_STEPS4 = ((-1, 0), (1, 0), (0, -1), (0, 1))
_STEPS8 = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0))


def _name(cell: Cell) -> str:
    return f"row {cell[0]}, col {cell[1]}"


def _neighbours(cell: Cell, size: int, steps: Iterable[Cell] = _STEPS4) -> Iterable[Cell]:
    r, c = cell
    for dr, dc in steps:
        rr, cc = r + dr, c + dc
        if 0 <= rr < size and 0 <= cc < size:
            yield rr, cc


@functools.cache
def _cell_neighbours(size: int) -> dict[Cell, tuple[Cell, ...]]:
    """Each cell's 4-neighbours, in :func:`_neighbours`' order: a contention's candidates are flooded and
    searched thousands of times. Cached; nothing changes a table."""
    return {(r, c): tuple(_neighbours((r, c), size)) for r in range(size) for c in range(size)}


def _flood(start: Cell, size: int, blocked: set[Cell] | frozenset[Cell]) -> set[Cell]:
    """Cells 4-connected to ``start`` that are not blocked."""
    neighbours = _cell_neighbours(size)
    seen = {start}
    todo = [start]
    while todo:
        for nxt in neighbours[todo.pop()]:
            if nxt not in seen and nxt not in blocked:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def _nearest(distances: np.ndarray) -> int:
    """The index of the least of ``distances`` to each chest (the lower index on equal distance), ignoring
    the unreachable (``-1``); ``-1`` when none is reachable."""
    reachable = [(int(d), j) for j, d in enumerate(distances) if d >= 0]
    return min(reachable)[1] if reachable else -1


@dataclass(frozen=True)
class GridMap:
    """A validated map. Build it with :func:`parse_layout`, which checks every rule."""

    size: int
    rows: tuple[str, ...]
    chests: tuple[Cell, ...]  # row-major: the order of the `treasures` and `assignment` segments
    traps: tuple[Cell, ...]
    starts: tuple[Cell, ...]  # index = agent
    obstacles: frozenset[Cell]

    @property
    def layout(self) -> str:
        return "\n".join(self.rows)

    @property
    def num_agents(self) -> int:
        return len(self.starts)

    @property
    def num_treasures(self) -> int:
        return len(self.chests)

    @property
    def num_traps(self) -> int:
        return len(self.traps)

    def distances_from(self, cell: Cell) -> np.ndarray:
        """BFS path lengths from ``cell`` avoiding obstacles and traps, ``-1`` where unreachable.

        Grid moves are symmetric, so this is also the distance *to* ``cell`` from everywhere: the
        deliberative coordinator computes it once per chest.
        """
        blocked = self.obstacles | frozenset(self.traps)
        neighbours = _cell_neighbours(self.size)
        steps = {cell: 0}
        queue = deque([cell])
        while queue:
            cur = queue.popleft()
            for nxt in neighbours[cur]:
                if nxt not in steps and nxt not in blocked:
                    steps[nxt] = steps[cur] + 1
                    queue.append(nxt)
        dist = np.full((self.size, self.size), -1, dtype=np.int64)
        rows, cols = zip(*steps)
        dist[rows, cols] = list(steps.values())
        return dist

    def nearest_chest(self, cell: Cell) -> int:
        """The chest nearest ``cell`` by a path avoiding obstacles and traps (the lower number on equal
        distance): the one a lone agent starting there reaches soonest. ``-1``: none reachable."""
        dist = self.distances_from(cell)
        return _nearest(np.array([dist[chest] for chest in self.chests]))

    def with_start_of(self, agent: int) -> GridMap:
        """This map with agent ``agent``'s start as agent 0's (the two start digits swapped), so that
        its single-agent task (agent 0 alone) starts from ``agent``'s cell; agent 0: the map itself."""
        if agent == 0:
            return self
        digits = {"0": str(agent), str(agent): "0"}
        return parse_layout("\n".join("".join(digits.get(ch, ch) for ch in row) for row in self.rows))

    def start_distances(self) -> np.ndarray:
        """``[m, k]`` BFS path lengths from each agent's start to each chest around obstacles and traps
        (:meth:`distances_from`), ``-1`` where unreachable."""
        rows, cols = np.array(self.starts).T
        return np.stack([self.distances_from(chest)[rows, cols] for chest in self.chests], axis=1)

    def nearest_chests(self) -> np.ndarray:
        """``[m]`` each agent's :meth:`nearest_chest` from its start (rule 3 makes every chest reachable on a
        valid map; ``-1``: none), from one search per chest (:meth:`start_distances`)."""
        return np.array([_nearest(row) for row in self.start_distances()])

    def contention(self) -> float:
        """The fraction of agents whose nearest chest (:meth:`nearest_chests`) is also another agent's."""
        nearest = self.nearest_chests()
        shared = [chest >= 0 and np.count_nonzero(nearest == chest) > 1 for chest in nearest]
        return float(np.mean(shared))


def parse_layout(text: str) -> GridMap:
    """Parse and validate an ASCII layout; a broken rule raises ``ValueError`` naming rule and cell.

    Blank leading/trailing lines and trailing whitespace are ignored, so layouts can be pasted
    from files or triple-quoted strings as they are.
    """
    lines = [line.rstrip() for line in text.splitlines()]
    while lines and not lines[0]:
        lines.pop(0)
    while lines and not lines[-1]:
        lines.pop()
    if not lines:
        raise ValueError("layout is empty")
    width = len(lines[0])
    for r, line in enumerate(lines):
        if len(line) != width:
            raise ValueError(f"layout has ragged rows: row 0 has {width} cells but row {r} has {len(line)}")
    size = len(lines)
    if width != size:
        raise ValueError(f"layout is not square: {size} rows of {width} cells (it must be n x n)")
    if size < 2:
        raise ValueError("layout must be at least 2 x 2")

    obstacles: set[Cell] = set()
    chests: list[Cell] = []
    traps: list[Cell] = []
    starts: dict[int, Cell] = {}
    for r, line in enumerate(lines):
        for c, ch in enumerate(line):
            if ch not in LEGEND:
                raise ValueError(f"unknown character {ch!r} at {_name((r, c))} (legend: . # T X 0-9)")
            if ch == OBSTACLE:
                obstacles.add((r, c))
            elif ch == CHEST:
                chests.append((r, c))
            elif ch == TRAP:
                traps.append((r, c))
            elif ch.isdigit():
                if int(ch) in starts:
                    raise ValueError(
                        f"start digit {ch} appears twice: at {_name(starts[int(ch)])} and at {_name((r, c))}"
                    )
                starts[int(ch)] = (r, c)
    if not starts:
        raise ValueError("layout has no agent start: put the digit 0 on a cell")
    missing = sorted(set(range(max(starts) + 1)) - set(starts))
    if missing:
        raise ValueError(f"start digits must be 0..m-1 without gaps: found {sorted(starts)}, missing {missing}")
    if not chests:
        raise ValueError("layout has no treasure chest 'T'")

    open_cells = {(r, c) for r in range(size) for c in range(size)} - obstacles
    region = _flood(starts[0], size, obstacles)
    if region != open_cells:
        cut = min(open_cells - region)
        raise ValueError(
            f"closed area: cell at {_name(cut)} is walled off from start 0 at {_name(starts[0])} "
            "(all non-obstacle cells must be 4-connected)"
        )
    chest_set = set(chests)
    for trap in traps:
        for nb in _neighbours(trap, size, _STEPS8):
            if nb in chest_set:
                raise ValueError(f"trap at {_name(trap)} is beside treasure at {_name(nb)}")
    blocked = obstacles | set(traps)
    for agent in sorted(starts):
        reach = _flood(starts[agent], size, blocked)
        for chest in chests:
            if chest not in reach:
                raise ValueError(
                    f"treasure at {_name(chest)} is unreachable from start {agent} at "
                    f"{_name(starts[agent])} without crossing obstacles or traps"
                )
    return GridMap(
        size=size,
        rows=tuple(lines),
        chests=tuple(chests),
        traps=tuple(traps),
        starts=tuple(starts[i] for i in range(len(starts))),
        obstacles=frozenset(obstacles),
    )


def optimal_team_return(
    grid_map: GridMap,
    num_agents: int,
    treasure_reward: float = 100.0,
    step_reward: float = -1.0,
) -> float | None:
    """The best team return any policy can get on ``grid_map`` with its first ``num_agents`` starts.

    Every agent walks a shortest path (around obstacles and traps) to a chest of its own, the agents
    matched to the chests so that the total distance is smallest (``linear_sum_assignment`` on the
    BFS distances of :meth:`GridMap.distances_from`). An agent ``d`` moves from its chest earns
    ``treasure_reward + (d - 1) * step_reward``: ``d - 1`` ordinary moves, then the move into the
    chest. This is the optimum under the default rewards (``step_reward <= 0``, and taking a chest
    beats ending any other way) and horizon (``max_steps = n * n`` exceeds every BFS distance);
    agents may share cells, so they never get in each other's way. The team return counts each
    reward once, so it is the same in both reward modes.

    ``None`` when there are more agents than chests: the agents left without a chest then wander
    until the horizon or a trap, which is no clean optimum. Also ``None`` if the agents cannot all
    reach chests of their own (impossible on a valid map, where every start reaches every chest).
    """
    if (
        isinstance(num_agents, bool)
        or not isinstance(num_agents, (int, np.integer))
        or not (1 <= num_agents <= grid_map.num_agents)
    ):
        raise ValueError(f"num_agents must be between 1 and the map's {grid_map.num_agents} starts, got {num_agents!r}")
    if num_agents > grid_map.num_treasures:
        return None
    # Imported here: scipy.optimize is 0.65 s of a start-up, and only this bound uses it.
    from scipy.optimize import linear_sum_assignment

    dist = grid_map.start_distances()[:num_agents]
    unreachable = grid_map.size**2 * num_agents + 1  # more than any matching of reachable pairs
    agents, chests = linear_sum_assignment(np.where(dist < 0, unreachable, dist))
    picked = dist[agents, chests]
    if (picked < 0).any():
        return None
    return float(num_agents * treasure_reward + (int(picked.sum()) - num_agents) * step_reward)


def _check_int(name: str, value: object, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < low or (high is not None and value > high):
        bound = f">= {low}" if high is None else f"between {low} and {high}"
        raise ValueError(f"{name} must be {bound}, got {value}")
    return int(value)


@functools.cache
def _neighbour_table(size: int, steps: tuple[Cell, ...]) -> list[list[int]]:
    """Flat-index neighbours of every cell: generation floods thousands of times, so it works on
    integers and a ``bytearray`` of blocked cells rather than tuples and sets. Cached for a contention's
    candidate draws; nothing changes a table."""
    return [[r * size + c for r, c in _neighbours(divmod(i, size), size, steps)] for i in range(size * size)]


def _joined(targets: list[int], nbrs: list[list[int]], blocked: bytearray) -> bool:
    """True if all ``targets`` lie in one unblocked component (the flood stops once they are)."""
    remaining = set(targets[1:])
    seen = {targets[0]}
    todo = [targets[0]]
    while todo and remaining:
        for nxt in nbrs[todo.pop()]:
            if nxt not in seen and not blocked[nxt]:
                seen.add(nxt)
                remaining.discard(nxt)
                todo.append(nxt)
    return not remaining


def _splits(cell: int, nbrs: list[list[int]], blocked: bytearray) -> bool:
    """Whether blocking ``cell`` (already marked) separates its open neighbours from each other."""
    open_nbs = [nb for nb in nbrs[cell] if not blocked[nb]]
    return len(open_nbs) > 1 and not _joined(open_nbs, nbrs, blocked)


def _place_obstacles(count: int, nbrs: list[list[int]], rng: np.random.Generator) -> bytearray:
    """Add obstacles one at a time at random, rejecting any that would split the open cells.

    Always succeeds while at least one open cell would remain: a leaf of a spanning tree of the
    open cells can always be removed, so every pass over the candidates accepts at least one.
    """
    blocked = bytearray(len(nbrs))
    candidates = rng.permutation(len(nbrs)).tolist()
    placed = 0
    while placed < count:
        rejected = []
        for cell in candidates:
            if placed == count:
                break
            blocked[cell] = 1
            if _splits(cell, nbrs, blocked):
                blocked[cell] = 0
                rejected.append(cell)
            else:
                placed += 1
        candidates = rejected
    return blocked


def _place_objects(
    obstacles: bytearray,
    num_treasures: int,
    num_traps: int,
    num_agents: int,
    nbrs: list[list[int]],
    nbrs8: list[list[int]],
    rng: np.random.Generator,
) -> tuple[list[int], list[int], list[int]] | None:
    """Chests and starts at random on free cells, then traps one at a time, each rejected if it
    touches a chest or cuts a chest off from a start; ``None`` if the traps do not fit."""
    free = [i for i, b in enumerate(obstacles) if not b]
    picks = rng.permutation(len(free))[: num_treasures + num_agents].tolist()
    chests = sorted(free[i] for i in picks[:num_treasures])
    starts = [free[i] for i in picks[num_treasures:]]
    excluded = set(chests) | set(starts) | {nb for ch in chests for nb in nbrs8[ch]}
    candidates = [cell for cell in free if cell not in excluded]
    if len(candidates) < num_traps:
        return None
    keys = chests + starts
    blocked = bytearray(obstacles)
    traps: list[int] = []
    for tried, i in enumerate(rng.permutation(len(candidates)).tolist()):
        if len(traps) == num_traps or len(traps) + len(candidates) - tried < num_traps:
            break
        cell = candidates[i]
        blocked[cell] = 1
        if _splits(cell, nbrs, blocked) and not _joined(keys, nbrs, blocked):
            blocked[cell] = 0
        else:
            traps.append(cell)
    if len(traps) < num_traps:
        return None
    return chests, sorted(traps), starts


def generate_layout(
    size: int,
    num_treasures: int,
    num_traps: int | None = None,
    num_agents: int | None = None,
    complexity: float = 0.0,
    seed: int | None = None,
    contention: Contention | str = Contention.any,
) -> str:
    """A random layout obeying every map rule, with ``round(complexity * size * size)`` obstacles.

    ``num_traps`` and ``num_agents`` default to ``num_treasures``. The same ``seed`` gives the same
    map. ``contention`` other than ``any`` draws candidates ``k = 0, 1, ...``, candidate ``k`` from the
    ``k``-th child of ``SeedSequence(seed)`` (``spawn_key=(k,)``, as ``SeedSequence.spawn`` makes it), and
    returns the first whose :meth:`GridMap.contention` is ``HIGH_CONTENTION`` (``high``: every agent
    shares its nearest chest) or 0 (``low``: none does), of at most ``CONTENTION_CANDIDATES``. An
    infeasible request raises ``ValueError`` naming the parameter after a bounded number of attempts (it
    never loops forever).
    """
    size = _check_int("size", size, 2)
    num_treasures = _check_int("num_treasures", num_treasures, 1)
    num_traps = _check_int("num_traps", num_treasures if num_traps is None else num_traps, 0)
    if num_agents is None and num_treasures > MAX_AGENTS:
        raise ValueError(
            f"num_agents defaults to num_treasures={num_treasures}, more than the {MAX_AGENTS} "
            "start digits: give num_agents"
        )
    num_agents = _check_int("num_agents", num_treasures if num_agents is None else num_agents, 1, MAX_AGENTS)
    if isinstance(complexity, bool) or not isinstance(complexity, (int, float, np.floating)):
        raise ValueError(f"complexity must be a number in [0, 1), got {complexity!r}")
    if not 0.0 <= complexity < 1.0:
        raise ValueError(f"complexity must be in [0, 1), got {complexity}")
    contention = check_enum("contention", contention, Contention)
    cells = size * size
    num_obstacles = round(complexity * size * size)  # round(Rc * n * n)
    num_objects = num_treasures + num_traps + num_agents
    if num_objects > cells:
        raise ValueError(
            f"num_treasures + num_traps + num_agents = {num_objects} objects do not fit on a "
            f"{size} x {size} map (size={size}, {cells} cells)"
        )
    if num_objects > cells - num_obstacles:
        raise ValueError(
            f"complexity={complexity} puts {num_obstacles} obstacles on a {size} x {size} map, "
            f"leaving {cells - num_obstacles} free cells for num_treasures + num_traps + "
            f"num_agents = {num_objects} objects"
        )
    if contention is Contention.high and num_agents < 2:
        raise ValueError("contention=high needs agents that share a nearest chest: give num_agents >= 2")
    if contention is Contention.low and num_agents > num_treasures:
        raise ValueError(
            f"contention=low gives every agent a nearest chest of its own: num_agents={num_agents} is more "
            f"than num_treasures={num_treasures}"
        )
    counts = (num_treasures, num_traps, num_agents)
    if isinstance(seed, int):
        return _seeded_layout(size, counts, complexity, seed, contention, CONTENTION_CANDIDATES)
    return _layout(size, counts, complexity, seed, contention, CONTENTION_CANDIDATES)


def _layout(
    size: int,
    counts: tuple[int, int, int],
    complexity: float,
    seed: int | None,
    contention: Contention,
    candidates: int,
) -> str:
    """:func:`generate_layout`'s map, its arguments checked; ``counts``: chests, traps, agents; ``candidates``:
    how many a contention draws at most."""
    num_treasures, num_traps, num_agents = counts
    if contention is Contention.any:
        return _draw_layout(size, *counts, complexity, np.random.default_rng(seed))
    entropy = np.random.SeedSequence(seed).entropy  # the seed itself; fresh entropy for None
    for candidate in range(candidates):
        rng = np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=(candidate,)))
        layout = _draw_layout(size, *counts, complexity, rng)
        share = parse_layout(layout).contention()
        if share == (HIGH_CONTENTION if contention is Contention.high else 0.0):
            return layout
    raise ValueError(
        f"no map of contention={contention.value} among the {candidates} candidates of seed {seed} "
        f"(size={size}, num_treasures={num_treasures}, num_traps={num_traps}, num_agents={num_agents}, "
        f"complexity={complexity})"
    )


# A seeded map is a function of its arguments, and an analysis plays each map once per mode and team:
# generating one of contention high or low takes tens of candidates (~50 ms).
_seeded_layout = functools.lru_cache(maxsize=4096)(_layout)


def _draw_layout(
    size: int, num_treasures: int, num_traps: int, num_agents: int, complexity: float, rng: np.random.Generator
) -> str:
    """One layout drawn with ``rng``, the arguments checked by :func:`generate_layout`."""
    cells = size * size
    nbrs, nbrs8 = _neighbour_table(size, _STEPS4), _neighbour_table(size, _STEPS8)
    obstacle_attempts = max(_MIN_OBSTACLE_ATTEMPTS, _WORK_BUDGET // 10 // cells)
    object_attempts = max(_MIN_OBJECT_ATTEMPTS, _WORK_BUDGET // cells)
    for _ in range(obstacle_attempts):
        obstacles = _place_obstacles(round(complexity * size * size), nbrs, rng)
        for _ in range(object_attempts):
            placed = _place_objects(obstacles, num_treasures, num_traps, num_agents, nbrs, nbrs8, rng)
            if placed is not None:
                return _render(size, obstacles, *placed)
    raise ValueError(
        f"num_traps={num_traps} traps do not fit on a {size} x {size} map with "
        f"num_treasures={num_treasures}, num_agents={num_agents} and complexity={complexity}: "
        "no trap may touch a treasure or cut one off from a start "
        f"({obstacle_attempts * object_attempts} placements tried)"
    )


def _render(size: int, obstacles: bytearray, chests: list[int], traps: list[int], starts: list[int]) -> str:
    grid = [OBSTACLE if blocked else FREE for blocked in obstacles]
    for mark, cells in ((CHEST, chests), (TRAP, traps)):
        for cell in cells:
            grid[cell] = mark
    for agent, cell in enumerate(starts):
        grid[cell] = str(agent)
    return "\n".join("".join(grid[r * size : (r + 1) * size]) for r in range(size))


def resolve_map(
    size: int | None = None,
    num_treasures: int | None = None,
    num_traps: int | None = None,
    num_agents: int | None = None,
    complexity: float | None = None,
    map_seed: int | None = None,
    contention: Contention | str | None = None,
    layout: str | None = None,
    layout_file: str | Path | None = None,
) -> GridMap:
    """The run's map: the given layout (string or file) if any, else a generated one.

    ``None`` means "not given": a generated map then takes the default of
    :class:`~dqn_transfer.envs.settings.EnvConfig`, so the map of a run is fixed unless asked otherwise.
    A layout fixes the size and the counts, so the generation parameters are ignored; one warning
    names those given that differ from the layout (``map_seed`` has no counterpart in a layout and
    is named when given and not 0). A contention other than ``any`` chooses among generated maps, so a
    layout with one is refused.
    """
    if layout is not None and layout_file is not None:
        raise ValueError("give either layout or layout_file, not both")
    contention = check_enum("contention", DEFAULTS.contention if contention is None else contention, Contention)
    if contention is not Contention.any and (layout is not None or layout_file is not None):
        raise ValueError(
            f"contention={contention.value} chooses among generated maps; a layout fixes the map "
            "(leave contention at any, or drop the layout)"
        )
    if layout_file is not None:
        try:
            layout = Path(layout_file).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
            raise ValueError(f"cannot read layout_file '{layout_file}': {reason}") from None
    if layout is None:
        return parse_layout(
            generate_layout(
                DEFAULTS.size if size is None else size,
                DEFAULTS.num_treasures if num_treasures is None else num_treasures,
                DEFAULTS.num_traps if num_traps is None else num_traps,
                DEFAULTS.num_agents if num_agents is None else num_agents,
                DEFAULTS.complexity if complexity is None else complexity,
                seed=DEFAULTS.map_seed if map_seed is None else map_seed,
                contention=contention,
            )
        )
    grid_map = parse_layout(layout)
    given = {"size": size, "num_treasures": num_treasures, "num_traps": num_traps, "num_agents": num_agents}
    actual = {
        "size": grid_map.size,
        "num_treasures": grid_map.num_treasures,
        "num_traps": grid_map.num_traps,
        "num_agents": grid_map.num_agents,
    }
    differing = [
        f"{key}={value} (layout: {actual[key]})"
        for key, value in given.items()
        if value is not None and value != actual[key]
    ]
    if complexity is not None and round(complexity * grid_map.size * grid_map.size) != len(grid_map.obstacles):
        differing.append(f"complexity={complexity} (layout: {len(grid_map.obstacles)} obstacles)")
    if map_seed not in (None, 0):
        differing.append(f"map_seed={map_seed} (a layout is not generated)")
    if differing:
        warnings.warn(
            "a layout fixes the map; ignoring generation parameters: " + ", ".join(differing),
            UserWarning,
            stacklevel=2,
        )
    return grid_map
