"""The batched core (``dqn_transfer/envs/batched.py``) against the one-game core, step by step.

Every replica of a batch is shadowed by its own :class:`TreasureHuntGame` on the same map, reset with
a generator seeded like the replica's, and both play the same action streams (half greedy towards the
nearest chest, so agents reach chests, meet there and tie, half random, so they hit traps, obstacles
and empty chests). After every joint step every array of the outcome and of the state is compared
bit-exactly with the one-game core's; episodes end (all agents done or truncated) and restart many
times in every case.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dqn_transfer.envs.batched import assign_batch, batch_maps, reset, reset_where, step
from dqn_transfer.envs.game import ACTION_MOVES, TreasureHuntGame, assign_agents
from dqn_transfer.envs.maps import GridMap, generate_layout, parse_layout

# Agents 0/1 and 2/3 flank a chest each: ties on nearly every episode.
TIE_MAP = """
0T1.X.
..#...
2T3...
......
.#...X
...T..
"""


def greedy_table(grid_map: GridMap) -> np.ndarray:
    """``[cells]`` the action that brings an agent closest to some chest (first on equal distance)."""
    n = grid_map.size
    dist = np.min([np.where(d < 0, 10**6, d) for d in map(grid_map.distances_from, grid_map.chests)], axis=0)
    best = np.zeros(n * n, dtype=np.int64)
    for r, c in itertools.product(range(n), range(n)):
        scores = []
        for dr, dc in ACTION_MOVES:
            rr, cc = r + dr, c + dc
            inside = 0 <= rr < n and 0 <= cc < n and (rr, cc) not in grid_map.obstacles
            scores.append(dist[rr, cc] if inside else 10**6)
        best[r * n + c] = int(np.argmin(scores))
    return best


def play_both(grid_maps: list[GridMap], steps: int, seed: int, auto_reset: bool = True, **rules) -> dict[str, int]:
    """Step a batch of ``grid_maps`` and one game per map side by side, asserting agreement; returns
    counts of what happened (to show the case exercised it)."""
    replicas = len(grid_maps)
    maps = batch_maps(grid_maps, auto_reset=auto_reset, **rules)
    games = [TreasureHuntGame(m, **rules) for m in grid_maps]
    game_rngs = [np.random.default_rng([seed, r]) for r in range(replicas)]
    batch_rngs = [np.random.default_rng([seed, r]) for r in range(replicas)]
    greedy = np.stack([greedy_table(m) for m in grid_maps])
    policy = np.random.default_rng(seed)
    state, obs = reset(maps, batch_rngs)
    for r, game in enumerate(games):
        assert_bits(obs[r], game.reset(game_rngs[r]))
    counts = dict.fromkeys(["steps", "collected", "traps", "truncated", "episodes", "ties"], 0)
    sums = np.zeros((replicas, maps.num_agents), dtype=np.float32)
    n = maps.size
    for _ in range(steps):
        cells = np.stack([g.positions[:, 0] * n + g.positions[:, 1] for g in games])
        actions = np.where(
            policy.random(cells.shape) < 0.5,
            greedy[np.arange(replicas)[:, None], cells],
            policy.integers(0, 4, cells.shape),
        )
        full_before = [g.chest_full for g in games]
        live_before = [g.live for g in games]
        state, out = step(maps, state, actions, batch_rngs)
        for r, game in enumerate(games):
            expected = game.step(actions[r])
            assert_bits(out.final_obs[r], expected.obs)
            for name in ("rewards", "terminated", "truncated", "trap", "bounced", "live"):
                assert_bits(getattr(out, name)[r], getattr(expected, name))
            assert out.treasures_collected[r] == expected.treasures_collected
            sums[r] += expected.rewards
            assert_bits(out.episode_return[r], sums[r])
            entered = [
                tuple(cell)
                for cell, was in zip(game.positions.tolist(), live_before[r])
                if was and tuple(cell) in game.map.chests and full_before[r][game.map.chests.index(tuple(cell))]
            ]
            counts["ties"] += len(entered) - len(set(entered))
            counts["collected"] += expected.treasures_collected
            counts["traps"] += int(expected.trap.sum())
            counts["truncated"] += int(expected.truncated.any())
            assert out.episode_end[r] == game.done
            if game.done:
                counts["episodes"] += 1
                sums[r] = 0
                if auto_reset:
                    assert_bits(out.obs[r], game.reset(game_rngs[r]))
            else:
                assert_bits(out.obs[r], expected.obs)
            if not game.done or auto_reset:  # the state is the one-game core's
                assert_bits(state.pos[r], game.positions[:, 0] * n + game.positions[:, 1])
                assert_bits(state.live[r], game.live)
                assert_bits(state.chest_full[r], game.chest_full)
                assert_bits(state.assigned[r], game.assignment)
                assert state.t[r] == game.steps
                assert state.treasures_collected[r] == game.treasures_collected
                assert_bits(state.obs[r], out.obs[r])
        if not auto_reset and out.episode_end.any():
            state = reset_where(maps, state, out.episode_end)
            for r in np.flatnonzero(out.episode_end).tolist():
                assert_bits(state.obs[r], games[r].reset(game_rngs[r]))
        counts["steps"] += replicas
    return counts


def assert_bits(got: np.ndarray, expected: np.ndarray) -> None:
    got, expected = np.asarray(got), np.asarray(expected)
    assert got.dtype == expected.dtype and got.shape == expected.shape, (got.dtype, expected.dtype)
    assert got.tobytes() == expected.tobytes(), (got, expected)


def generated(size: int, seeds: range, chests: int, agents: int = 4) -> list[GridMap]:
    return [
        parse_layout(generate_layout(size, chests, num_agents=agents, complexity=0.15, seed=seed)) for seed in seeds
    ]


CASES = list(itertools.product(["competitive", "cooperative", "deliberative"], [6, 8, 10], ["individual", "team"]))


@pytest.mark.parametrize("mode, size, reward_mode", CASES)
def test_batched_core_agrees_with_the_one_game_core(mode, size, reward_mode):
    number = CASES.index((mode, size, reward_mode))
    chests = 2 + number % 3  # 2, 3 or 4 chests for 4 agents
    rules = dict(
        mode=mode,
        reward_mode=reward_mode,
        obs_encoding=("onehot", "coords")[number % 2],
        view_radius=(0, 1, 2)[number % 3],
        max_steps=(None, 2 * size)[number // 2 % 2],
    )
    counts = play_both(generated(size, range(4 * number, 4 * number + 4), chests), 800, number, **rules)
    assert counts["steps"] == 3200
    assert counts["collected"] > 20 and counts["episodes"] > 20, counts
    assert counts["traps"] > 0 and counts["truncated"] > 0, counts


@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
@pytest.mark.parametrize("auto_reset", [True, False])
def test_chest_ties_draw_like_the_one_game_core(mode, auto_reset):
    tie_map = parse_layout(TIE_MAP)
    other = parse_layout(TIE_MAP.replace("...T..", "..T...").replace("X.\n", ".X\n", 1))
    counts = play_both(
        [tie_map, other, tie_map], 600, 7, auto_reset=auto_reset, mode=mode, reward_mode="team", max_steps=12
    )
    assert counts["ties"] > 50, counts


def test_fewer_agents_than_starts_and_no_treasures_segment():
    grid_maps = generated(6, range(3), 2)
    play_both(grid_maps, 300, 1, num_agents=2, include_treasures=False, view_radius=1)


def test_batched_assignment_matches_assign_agents_on_tie_heavy_matrices():
    rng = np.random.default_rng(0)
    for rows, cols in itertools.product(range(1, 6), range(1, 6)):
        cost = rng.integers(0, 3, size=(40, rows, cols))
        expected = np.stack([assign_agents(matrix) for matrix in cost])
        assert_bits(assign_batch(cost), expected)


def test_maps_of_different_sizes_or_counts_are_refused():
    six, eight = generated(6, range(1), 2)[0], generated(8, range(1), 2)[0]
    with pytest.raises(ValueError, match="share their size, agent count and chest count.*size 6.*size 8"):
        batch_maps([six, eight])
    with pytest.raises(ValueError, match="3 chests"):
        batch_maps([six, generated(6, range(1), 3)[0]])
    with pytest.raises(ValueError, match="2 agents"):
        batch_maps([six, *generated(6, range(1), 2, agents=2)])


def test_bad_actions_and_finished_replicas_are_refused():
    maps = batch_maps(generated(6, range(2), 2), max_steps=1)
    rngs = [np.random.default_rng(r) for r in range(2)]
    state, _ = reset(maps, rngs)
    with pytest.raises(ValueError, match="shape"):
        step(maps, state, np.zeros((2, 3), dtype=np.int64), rngs)
    with pytest.raises(ValueError, match="0..3"):
        step(maps, state, np.full((2, 4), 4), rngs)
    before = [array.copy() for array in state]
    later, out = step(maps, state, np.zeros((2, 4), dtype=np.int64), rngs)
    assert all(np.array_equal(a, b) for a, b in zip(state, before))  # the input state is unchanged
    assert out.episode_end.all() and out.truncated.any()
    with pytest.raises(RuntimeError, match="replicas \\[0, 1\\]"):
        step(maps, later, np.zeros((2, 4), dtype=np.int64), rngs)
