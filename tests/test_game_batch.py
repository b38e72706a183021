"""The training loop's game batch: R games stepped as one batch and the same games stepped one by one
give the same steps, resets and saved episodes, bit for bit (a replica is the lone game of its seed), and
a replica's saved episode continues in either."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts
from dqn_transfer.envs.game_batch import LoopedGames, game_batch
from dqn_transfer.envs.maps import GridMap, generate_layout, parse_layout
from dqn_transfer.envs.rules import ACTION_MOVES

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


def games_of(layouts: list[str], **rules) -> list[TreasureHuntGame]:
    return [TreasureHuntGame(parse_layout(layout), **rules) for layout in layouts]


def started(games: list[TreasureHuntGame], seed: int) -> tuple[list[TreasureHuntGame], list[np.random.Generator]]:
    rngs = [np.random.default_rng([seed, r]) for r in range(len(games))]
    for game, rng in zip(games, rngs):
        game.reset(rng)
    return games, rngs


LAYOUTS = [TIE_MAP, *(generate_layout(6, 3, 2, 4, 0.1, seed) for seed in (1, 2))]


@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
def test_one_batch_and_the_loop_agree_step_by_step_and_across_a_saved_episode(mode):
    rules = dict(mode=mode, max_steps=25)
    batch = TreasureHunts.of_games(*started(games_of(LAYOUTS, **rules), seed=3))
    looped = LoopedGames(*started(games_of(LAYOUTS, **rules), seed=3))
    greedy = np.stack([greedy_table(game.map) for game in looped.games])
    policy = np.random.default_rng(0)
    episodes = ties = 0
    for t in range(400):
        np.testing.assert_array_equal(batch.obs, looped.obs)
        np.testing.assert_array_equal(batch.live, looped.live)
        cells = np.stack([game.state_dict()["pos"] for game in looped.games])
        towards = np.take_along_axis(greedy, cells, axis=1)
        actions = np.where(policy.random(towards.shape) < 0.7, towards, policy.integers(0, 4, towards.shape))
        a, b = batch.step(actions), looped.step(actions)
        for name, x, y in zip(a._fields, a, b):
            np.testing.assert_array_equal(x, y, err_msg=f"{name} at step {t}")
        ties += int((a.treasures_collected > 0).sum())
        episodes += int(a.episode_end.sum())
        batch.reset(a.episode_end)
        looped.reset(a.episode_end)
        if t == 150:  # a mid-episode save of replica 1, continued in a fresh batch of each kind
            saved = [batch.state_dict(r) for r in range(3)]
            assert saved == [looped.state_dict(r) for r in range(3)]
            rngs = [np.random.default_rng([9, r]) for r in range(3)]
            for r, rng in enumerate(rngs):
                rng.bit_generator.state = batch.rngs[r].bit_generator.state
            batch = TreasureHunts.of_games(*started(games_of(LAYOUTS, **rules), seed=5))
            looped = LoopedGames(*started(games_of(LAYOUTS, **rules), seed=5))
            for r in range(3):
                looped.rngs[r].bit_generator.state = rngs[r].bit_generator.state
                batch.use_generator(r, rngs[r])  # handed over: its state is copied for the kernels
                batch.load_state_dict(r, saved[r])
                looped.load_state_dict(r, saved[r])
            assert [batch.state_dict(r) for r in range(3)] == saved
    assert episodes >= 20 and ties >= 20  # the streams ended many episodes and emptied many chests


def test_game_batch_steps_treasure_hunts_that_share_rules_and_size_as_one_batch():
    assert isinstance(game_batch(*started(games_of(LAYOUTS[1:2], mode="cooperative"), 0)), TreasureHunts)
    assert isinstance(game_batch(*started(games_of(2 * LAYOUTS, mode="cooperative"), 0)), TreasureHunts)
    mixed_rules = [*games_of(LAYOUTS[1:2], mode="cooperative"), *games_of(LAYOUTS[1:2], mode="competitive")]
    assert isinstance(game_batch(*started(mixed_rules, 0)), LoopedGames)


def test_a_saved_episode_that_does_not_fit_the_replica_is_refused_and_changes_nothing():
    batch = TreasureHunts.of_games(*started(games_of(LAYOUTS), seed=0))
    before = batch.state_dict(0)
    bad = {**before, "pos": [10**6] * 4}
    with pytest.raises(ValueError, match="outside the 6 x 6 grid"):
        batch.load_state_dict(0, bad)
    assert batch.state_dict(0) == before
