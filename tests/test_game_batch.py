"""The training loop's game batch: the batched core and the plain loop over games give the same steps,
resets and saved episodes, bit for bit, and a replica's saved episode continues in either."""

from __future__ import annotations

import numpy as np
import pytest
from test_batched_core import TIE_MAP, greedy_table

from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.game_batch import BATCHED_CORE_MIN_REPLICAS, BatchedTreasureHunts, LoopedGames, game_batch
from dqn_transfer.envs.maps import generate_layout, parse_layout


def games_of(layouts: list[str], **rules) -> list[TreasureHuntGame]:
    return [TreasureHuntGame(parse_layout(layout), **rules) for layout in layouts]


def started(games: list[TreasureHuntGame], seed: int) -> tuple[list[TreasureHuntGame], list[np.random.Generator]]:
    rngs = [np.random.default_rng([seed, r]) for r in range(len(games))]
    for game, rng in zip(games, rngs):
        game.reset(rng)
    return games, rngs


LAYOUTS = [TIE_MAP, *(generate_layout(6, 3, 2, 4, 0.1, seed) for seed in (1, 2))]


@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
def test_the_batched_core_and_the_loop_agree_step_by_step_and_across_a_saved_episode(mode):
    rules = dict(mode=mode, max_steps=25)
    batched = BatchedTreasureHunts(*started(games_of(LAYOUTS, **rules), seed=3))
    looped = LoopedGames(*started(games_of(LAYOUTS, **rules), seed=3))
    greedy = np.stack([greedy_table(game.map) for game in looped.games])
    policy = np.random.default_rng(0)
    episodes = ties = 0
    for t in range(400):
        np.testing.assert_array_equal(batched.obs, looped.obs)
        np.testing.assert_array_equal(batched.live, looped.live)
        cells = np.stack([game.state_dict()["pos"] for game in looped.games])
        towards = np.take_along_axis(greedy, cells, axis=1)
        actions = np.where(policy.random(towards.shape) < 0.7, towards, policy.integers(0, 4, towards.shape))
        a, b = batched.step(actions), looped.step(actions)
        for name, x, y in zip(a._fields, a, b):
            np.testing.assert_array_equal(x, y, err_msg=f"{name} at step {t}")
        ties += int((a.treasures_collected > 0).sum())
        episodes += int(a.episode_end.sum())
        batched.reset(a.episode_end)
        looped.reset(a.episode_end)
        if t == 150:  # a mid-episode save of replica 1, continued in a fresh batch of each kind
            saved = [batched.state_dict(r) for r in range(3)]
            assert saved == [looped.state_dict(r) for r in range(3)]
            rngs = [np.random.default_rng([9, r]) for r in range(3)]
            for r, rng in enumerate(rngs):
                rng.bit_generator.state = batched.rngs[r].bit_generator.state
            batched = BatchedTreasureHunts(*started(games_of(LAYOUTS, **rules), seed=5))
            looped = LoopedGames(*started(games_of(LAYOUTS, **rules), seed=5))
            for r in range(3):
                batched.rngs[r].bit_generator.state = rngs[r].bit_generator.state
                looped.rngs[r].bit_generator.state = rngs[r].bit_generator.state
                batched.load_state_dict(r, saved[r])
                looped.load_state_dict(r, saved[r])
            assert [batched.state_dict(r) for r in range(3)] == saved
    assert episodes >= 20 and ties >= 20  # the streams ended many episodes and emptied many chests


def test_game_batch_takes_the_batched_core_for_enough_treasure_hunts_that_share_a_batch():
    many = BATCHED_CORE_MIN_REPLICAS * LAYOUTS[1:]
    assert isinstance(game_batch(*started(games_of(many, mode="cooperative"), 0)), BatchedTreasureHunts)
    few = (BATCHED_CORE_MIN_REPLICAS - 1) * LAYOUTS[1:2]  # the loop is faster for a few
    assert isinstance(game_batch(*started(games_of(few, mode="cooperative"), 0)), LoopedGames)
    half = BATCHED_CORE_MIN_REPLICAS * LAYOUTS[1:2]
    mixed_rules = [*games_of(half, mode="cooperative"), *games_of(half, mode="competitive")]
    assert isinstance(game_batch(*started(mixed_rules, 0)), LoopedGames)


def test_a_saved_episode_that_does_not_fit_the_replica_is_refused_and_changes_nothing():
    batch = BatchedTreasureHunts(*started(games_of(LAYOUTS), seed=0))
    before = batch.state_dict(0)
    bad = {**before, "pos": [10**6] * 4}
    with pytest.raises(ValueError, match="outside the 6 x 6 grid"):
        batch.load_state_dict(0, bad)
    assert batch.state_dict(0) == before
