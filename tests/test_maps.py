"""Map generation and layout validation (rules: docs/game.md): every rule, checked independently."""

from __future__ import annotations

import functools
import itertools
import math
import time
import warnings

import numpy as np
import pytest

from dqn_transfer.envs.maps import GridMap, generate_layout, optimal_team_return, parse_layout, resolve_map


# ---------------------------------------------------------------- an independent rule checker
def _cells(rows: list[str], chars: str) -> list[tuple[int, int]]:
    return [(r, c) for r, row in enumerate(rows) for c, ch in enumerate(row) if ch in chars]


def _component(rows: list[str], start: tuple[int, int], walls: str) -> set[tuple[int, int]]:
    n = len(rows)
    seen, stack = {start}, [start]
    while stack:
        r, c = stack.pop()
        for rr, cc in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
            if 0 <= rr < n and 0 <= cc < n and (rr, cc) not in seen and rows[rr][cc] not in walls:
                seen.add((rr, cc))
                stack.append((rr, cc))
    return seen


def assert_map_rules(text: str, size: int, treasures: int, traps: int, agents: int, obstacles: int):
    rows = text.split("\n")
    assert len(rows) == size and all(len(row) == size for row in rows)
    assert set(text) <= set(".#TX0123456789\n")
    assert len(_cells(rows, "#")) == obstacles
    assert len(_cells(rows, "T")) == treasures
    assert len(_cells(rows, "X")) == traps
    digits = sorted(ch for row in rows for ch in row if ch.isdigit())
    assert digits == [str(i) for i in range(agents)]  # distinct, 0..m-1
    open_cells = set(_cells(rows, ".TX0123456789"))
    assert _component(rows, next(iter(open_cells)), "#") == open_cells  # no closed area
    for tr, tc in _cells(rows, "X"):
        for cr, cc in _cells(rows, "T"):
            assert max(abs(tr - cr), abs(tc - cc)) > 1, "trap beside a treasure"
    for start in _cells(rows, "0123456789"):
        reach = _component(rows, start, "#X")
        assert set(_cells(rows, "T")) <= reach


GRID = [
    # (size, num_treasures, num_traps, num_agents, complexity)
    (size, k, traps, agents, rc)
    for size in (4, 5, 7, 10)
    for k, traps, agents in ((1, 0, 1), (1, 1, 2), (2, 2, 2), (2, None, 4), (3, 1, None))
    for rc in (0.0, 0.1, 0.2, 0.35)
    if not (size == 4 and k == 3)
]


def test_generated_maps_obey_every_rule():
    checked = 0
    for (size, k, traps, agents, rc), seed in itertools.product(GRID, range(4)):
        text = generate_layout(size, k, traps, agents, rc, seed=seed)
        assert_map_rules(
            text,
            size,
            k,
            k if traps is None else traps,
            k if agents is None else agents,
            round(rc * size * size),
        )
        checked += 1
    assert checked >= 300


def test_larger_maps_and_ten_agents():
    for seed in range(5):
        text = generate_layout(16, 6, 8, 10, 0.3, seed=seed)
        assert_map_rules(text, 16, 6, 8, 10, round(0.3 * 16 * 16))


def test_obstacle_count_uses_python_round():
    # 0.1 * 5 * 5 = 2.5 -> round() gives 2 (round half to even); 0.3 * 5 * 5 = 7.5 -> 8
    assert generate_layout(5, 1, 0, 1, 0.1, seed=0).count("#") == 2
    assert generate_layout(5, 1, 0, 1, 0.3, seed=0).count("#") == 8


def test_counts_default_to_num_treasures():
    text = generate_layout(8, 3, seed=1)
    assert text.count("T") == 3 and text.count("X") == 3
    assert sorted(ch for ch in text if ch.isdigit()) == ["0", "1", "2"]


def test_same_seed_same_map_and_round_trip():
    a = generate_layout(9, 3, 2, 4, 0.2, seed=7)
    assert a == generate_layout(9, 3, 2, 4, 0.2, seed=7)
    assert a != generate_layout(9, 3, 2, 4, 0.2, seed=8)
    grid_map = parse_layout(a)
    assert grid_map.layout == a
    assert (grid_map.size, grid_map.num_treasures, grid_map.num_traps, grid_map.num_agents) == (
        9,
        3,
        2,
        4,
    )
    for seed in range(50):
        text = generate_layout(6, 2, 1, 3, 0.15, seed=seed)
        assert parse_layout(text).layout == text


# ---------------------------------------------------------------- parsing a hand layout
def test_parse_fields_row_major_and_whitespace():
    grid_map = parse_layout("\n\nT..1  \n.#..\n...T\t\n0X..\n\n  \n")
    assert grid_map.size == 4
    assert grid_map.rows == ("T..1", ".#..", "...T", "0X..")
    assert grid_map.chests == ((0, 0), (2, 3))  # row-major order
    assert grid_map.traps == ((3, 1),) and grid_map.starts == ((3, 0), (0, 3))
    assert grid_map.obstacles == frozenset({(1, 1)})


def test_distances_avoid_obstacles_and_traps():
    grid_map = parse_layout("0.#.\n..#.\n....\nT..X")
    dist = grid_map.distances_from((0, 0))
    assert dist[0, 3] == 7  # around the wall: (1,0)(2,0)(2,1)(2,2)(2,3)(1,3)(0,3)
    assert dist[3, 0] == 3 and dist[0, 2] == -1 and dist[3, 3] == -1  # obstacle, trap
    assert dist[2, 3] == 5


# ---------------------------------------------------------------- every bad layout
@pytest.mark.parametrize(
    ("layout", "match"),
    [
        ("", "layout is empty"),
        ("\n  \n", "layout is empty"),
        ("0.T\n..\n...", "ragged rows: row 0 has 3 cells but row 1 has 2"),
        ("0.T.\n....\n....", "not square: 3 rows of 4 cells"),
        ("0", "at least 2 x 2"),
        ("0.T\n.a.\n...", r"unknown character 'a' at row 1, col 1"),
        ("0.T\n...\n..0", "start digit 0 appears twice"),
        ("0.T\n...\n..2", r"without gaps: found \[0, 2\], missing \[1\]"),
        ("1.T\n...\n...", r"missing \[0\]"),
        ("..T\n...\n...", "no agent start"),
        ("0..\n...\n...", "no treasure chest"),
        ("0.#.\n..#T\n###.\n....", "closed area: cell at row 0, col 3"),
        ("0.....\n......\n..T...\n...X..\n......\n......", "trap at row 3, col 3 is beside treasure at row 2, col 2"),
        ("0....\n.....\n..#X#\n..#..\n..#.T", "treasure at row 4, col 4 is unreachable from start 0 at row 0, col 0"),
    ],
)
def test_bad_layouts_name_the_rule(layout, match):
    with pytest.raises(ValueError, match=match):
        parse_layout(layout)


def test_trap_beside_treasure_diagonal_and_unreachable_second_start():
    with pytest.raises(ValueError, match="trap at row 1, col 1 is beside treasure at row 0, col 0"):
        parse_layout("T..\n.X.\n..0")
    # agent 1 is walled in by traps: treasure fine for 0, unreachable for 1
    with pytest.raises(ValueError, match="unreachable from start 1 at row 3, col 3"):
        parse_layout("0.T.\n....\n...X\n..X1")


# ---------------------------------------------------------------- infeasible generation
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(size=1, num_treasures=1), "size must be >= 2"),
        (dict(size=5, num_treasures=0), "num_treasures must be >= 1"),
        (dict(size=5, num_treasures=1, num_traps=-1), "num_traps must be >= 0"),
        (dict(size=5, num_treasures=1, num_agents=11), "num_agents must be between 1 and 10"),
        (dict(size=9, num_treasures=11), "num_agents defaults to num_treasures=11"),
        (dict(size=5, num_treasures=1, complexity=1.0), r"complexity must be in \[0, 1\)"),
        (dict(size=5, num_treasures=1, complexity=-0.1), r"complexity must be in \[0, 1\)"),
        (dict(size=3, num_treasures=4, num_traps=4, num_agents=2), "num_treasures.*do not fit"),
        (dict(size=4, num_treasures=1, complexity=0.9), "complexity=0.9 puts 14 obstacles"),
        (dict(size=3, num_treasures=1, num_traps=7, num_agents=1), "num_traps=7 traps do not fit"),
        (dict(size=10, num_treasures=10, num_traps=60, num_agents=10), "num_traps=60"),
    ],
)
def test_infeasible_generation_names_the_parameter_and_returns_fast(kwargs, match):
    start = time.perf_counter()
    with pytest.raises(ValueError, match=match):
        generate_layout(**kwargs, seed=0)
    assert time.perf_counter() - start < 2.0


# ---------------------------------------------------------------- resolve_map
def test_resolve_map_generates_from_map_seed():
    a = resolve_map(7, 2, None, None, 0.1, 3)
    assert a.layout == generate_layout(7, 2, None, None, 0.1, seed=3)
    # the documented defaults (EnvConfig): 6x6, 2 chests, 2 traps, 2 agents, 10% obstacles, map_seed 0
    assert resolve_map().layout == generate_layout(6, 2, 2, 2, 0.1, seed=0)


def test_layout_wins_with_one_warning_naming_differing_params():
    layout = "0.T\n...\n..."
    with pytest.warns(UserWarning) as record:
        grid_map = resolve_map(size=10, num_treasures=1, num_traps=2, complexity=0.0, map_seed=5, layout=layout)
    assert grid_map.layout == layout
    assert len(record) == 1
    message = str(record[0].message)
    assert "size=10 (layout: 3)" in message and "num_traps=2 (layout: 0)" in message
    assert "map_seed=5" in message
    assert "num_treasures" not in message and "complexity" not in message
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        resolve_map(size=3, num_treasures=1, num_traps=0, num_agents=1, layout=layout)


def test_layout_file(tmp_path):
    path = tmp_path / "map.txt"
    path.write_text("\n0.T  \n...\n...\n\n")
    assert resolve_map(layout_file=str(path)).rows == ("0.T", "...", "...")
    with pytest.raises(ValueError, match="cannot read layout_file '.*missing.txt'"):
        resolve_map(layout_file=str(tmp_path / "missing.txt"))
    with pytest.raises(ValueError, match="cannot read layout_file"):
        resolve_map(layout_file=str(tmp_path))  # a directory
    (tmp_path / "bin.txt").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="cannot read layout_file"):
        resolve_map(layout_file=str(tmp_path / "bin.txt"))
    with pytest.raises(ValueError, match="either layout or layout_file"):
        resolve_map(layout="0T\n..", layout_file=str(path))


def test_generated_maps_spread_objects():
    """Sanity of the randomness: over many seeds every free cell gets a chest sometimes."""
    hits = np.zeros((5, 5), dtype=int)
    for seed in range(200):
        for r, c in parse_layout(generate_layout(5, 1, 0, 1, seed=seed)).chests:
            hits[r, c] += 1
    assert (hits > 0).all()


# ---------------------------------------------------------------- the map's optimal team return
def test_optimal_return_one_agent_three_moves_from_a_chest():
    # 2 ordinary moves, then the move into the chest: -1 - 1 + 100 = 98
    assert optimal_team_return(parse_layout("0..T\n....\n....\n...."), 1) == 98.0
    # other rewards: 10 + 2 * (-0.5) = 9
    assert optimal_team_return(parse_layout("0..T\n....\n....\n...."), 1, 10.0, -0.5) == 9.0


def test_optimal_return_matches_agents_to_chests_not_greedily():
    # chest 0 at (0,0), chest 1 at (0,3); agent 0 at (0,2), agent 1 at (0,5); open grid: Manhattan
    #   d(a0, c0) = 2, d(a0, c1) = 1, d(a1, c0) = 5, d(a1, c1) = 2
    #   greedy (a0 takes its nearest c1, a1 gets c0): 1 + 5 = 6 moves -> 200 - 4 = 196
    #   optimal (a0 -> c0, a1 -> c1): 2 + 2 = 4 moves -> 2 * 100 + (4 - 2) * (-1) = 198
    layout = "T.0T.1\n......\n......\n......\n......\n......"
    assert optimal_team_return(parse_layout(layout), 2) == 198.0
    assert optimal_team_return(parse_layout(layout), 1) == 100.0  # agent 0 alone: next to chest 1


def test_optimal_return_detours_around_a_trap_and_obstacles():
    # the straight path (0,0)->(0,4) is 4 moves but crosses the trap at (0,1); the detour through
    # row 1 is 6 moves: (1,0)(1,1)(1,2)(1,3)(1,4)(0,4) -> 100 - 5 = 95
    assert optimal_team_return(parse_layout("0X..T\n.....\n.....\n.....\n....."), 1) == 95.0
    # and with a wall on row 1 the detour goes down to row 2: 8 moves -> 100 - 7 = 93
    layout = "0X..T\n.###.\n.....\n.....\n....."
    assert optimal_team_return(parse_layout(layout), 1) == 93.0


def test_optimal_return_is_none_with_more_agents_than_chests():
    grid_map = parse_layout("0.T\n...\n..1")
    assert optimal_team_return(grid_map, 2) is None
    assert optimal_team_return(grid_map, 1) == 99.0  # only agent 0: 2 moves
    with pytest.raises(ValueError, match="num_agents must be between 1 and the map's 2 starts"):
        optimal_team_return(grid_map, 3)


def test_optimal_return_is_none_when_a_chest_cannot_be_reached():
    # not a valid map (parse_layout refuses it): the chest at (0,2) is walled off from the start
    walled = GridMap(
        size=3,
        rows=("0#T", ".##", "..."),
        chests=((0, 2),),
        traps=(),
        starts=((0, 0),),
        obstacles=frozenset({(0, 1), (1, 1), (1, 2)}),
    )
    assert optimal_team_return(walled, 1) is None


ACTIONS4 = ((-1, 0), (1, 0), (0, -1), (0, 1))


def exhaustive_optimum(text: str, num_agents: int, max_steps: int) -> float:
    """Best expected team return over all joint policies, by dynamic programming over every state,
    written from the rules of docs/game.md (ties for a chest: each contender wins equally often)."""
    rows = text.split("\n")
    n = len(rows)
    starts = sorted((rows[r][c], (r, c)) for r in range(n) for c in range(n) if rows[r][c].isdigit())
    starts = [cell for _, cell in starts][:num_agents]
    chests = [(r, c) for r in range(n) for c in range(n) if rows[r][c] == "T"]

    def move(agent, cell, action):
        r, c = cell[0] + ACTIONS4[action][0], cell[1] + ACTIONS4[action][1]
        if not (0 <= r < n and 0 <= c < n):
            return cell
        return starts[agent] if rows[r][c] == "#" else (r, c)

    @functools.cache
    def value(t, pos, live, full):
        if not any(live) or t == max_steps:
            return 0.0
        movers = [a for a in range(num_agents) if live[a]]
        best = -math.inf
        for acts in itertools.product(range(4), repeat=len(movers)):
            new = list(pos)
            for agent, action in zip(movers, acts):
                new[agent] = move(agent, pos[agent], action)
            reward, ended, now_full = 0.0, set(), list(full)
            contenders: dict[int, list[int]] = {}
            for agent in movers:
                cell = new[agent]
                if rows[cell[0]][cell[1]] == "X":
                    reward -= 100.0
                    ended.add(agent)
                elif cell in chests and full[chests.index(cell)]:
                    contenders.setdefault(chests.index(cell), []).append(agent)
                else:
                    reward -= 1.0
            for chest, group in contenders.items():
                now_full[chest] = False
                reward += 100.0 - (len(group) - 1)  # the winner's +100, every loser's -1
            outcomes = [()]
            for group in contenders.values():
                outcomes = [o + (w,) for o in outcomes for w in group]
            total = 0.0
            for winners in outcomes:
                done = ended | set(winners)
                next_live = tuple(live[a] and a not in done for a in range(num_agents))
                total += value(t + 1, tuple(new), next_live, tuple(now_full))
            best = max(best, reward + total / len(outcomes))
        return best

    return value(0, tuple(starts), (True,) * num_agents, (True,) * len(chests))


@pytest.mark.parametrize("seed", range(4))
def test_optimal_return_equals_an_exhaustive_search_on_small_maps(seed):
    text = generate_layout(4, num_treasures=2, num_traps=1, num_agents=2, complexity=0.15, seed=seed)
    grid_map = parse_layout(text)
    for agents in (1, 2):
        assert optimal_team_return(grid_map, agents) == exhaustive_optimum(text, agents, 16), text
