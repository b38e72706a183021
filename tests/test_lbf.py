"""Level-Based Foraging's faster observations and valid actions (``envs/lbf.FastForagingEnv``) against
lbforaging's own ``ForagingEnv``, and a batch of LBF games stepped by one kernel (``envs/lbf.ForagingBatch``)
against the same games stepped one by one through lbforaging: each pair is played side by side from the same
seeds with the same random actions, and every vector, valid-action list, reward and ending must be the same."""

from __future__ import annotations

import numpy as np
import pytest
from lbforaging.foraging.environment import ForagingEnv

from dqn_transfer.envs.game_batch import LoopedGames, game_batch
from dqn_transfer.envs.lbf import FastForagingEnv, ForagingBatch
from dqn_transfer.envs.pettingzoo_game import PettingZooGame

GAMES = {
    "whole_field_seen": dict(players=2, max_player_level=2, field_size=(8, 8), max_num_food=2, sight=8),
    "short_sight_at_the_edges": dict(players=4, max_player_level=3, field_size=(6, 6), max_num_food=3, sight=1),
    "sight_two_crowded": dict(players=3, max_player_level=2, field_size=(5, 7), max_num_food=4, sight=2),
    "levels_unseen_cooperative": dict(
        players=3,
        max_player_level=2,
        field_size=(7, 7),
        max_num_food=2,
        sight=3,
        observe_agent_levels=False,
        force_coop=True,
    ),
}


def both(kwargs: dict) -> tuple[ForagingEnv, FastForagingEnv]:
    settings = dict(min_player_level=1, min_food_level=1, max_food_level=None, max_episode_steps=25, force_coop=False)
    settings.update(kwargs)
    return ForagingEnv(**settings), FastForagingEnv(**settings)


@pytest.mark.parametrize("game", GAMES)
def test_the_faster_env_observes_and_plays_as_lbforaging(game):
    original, fast = both(GAMES[game])
    rng = np.random.default_rng(7)
    steps = partly_seen = food_seen = 0
    for episode in range(30):
        expected, _ = original.reset(seed=episode)
        observed, _ = fast.reset(seed=episode)
        done = False
        while True:
            assert len(observed) == len(expected)
            for mine, theirs in zip(observed, expected):
                assert mine.dtype == theirs.dtype and np.array_equal(mine, theirs)
                assert fast.observation_space[0].contains(mine)
            valid = [original._valid_actions[player] for player in original.players]
            assert [fast._valid_actions[player] for player in fast.players] == valid
            players = original.n_agents
            width = 3 if original._observe_agent_levels else 2
            vectors = np.stack(expected)
            player_rows = vectors[:, 3 * original.max_num_food :].reshape(players, players, width)
            partly_seen += int((player_rows[:, :, 0] == -1).any())
            food_seen += int((vectors[:, : 3 * original.max_num_food : 3] >= 0).any())
            if done:
                break
            actions = rng.integers(0, 6, size=players).tolist()
            expected, rewards, done, _, _ = original.step(actions)
            observed, fast_rewards, fast_done, _, _ = fast.step(actions)
            assert fast_rewards == rewards and fast_done == done
            steps += 1
    assert steps > 300 and food_seen > 0
    if GAMES[game]["sight"] < max(GAMES[game]["field_size"]):  # the seeing rule is exercised
        assert partly_seen > 0


BATCHES = {  # LevelBasedForaging's kwargs
    "the_studys_task": dict(size=8, players=2, food=2, max_player_level=1, max_food_level=1, max_steps=25),
    "levels_penalty_short_sight": dict(
        size=7, players=3, food=3, max_player_level=3, sight=2, penalty=0.5, max_steps=30
    ),
    "cooperative_food_crowded": dict(size=5, players=4, food=2, max_player_level=2, force_coop=True, penalty=0.25),
}


def lbf_games(kwargs: dict, fixed: bool, seed: int) -> tuple[list[PettingZooGame], list[np.random.Generator]]:
    """Four LBF games at the start of an episode, as a run's replicas are (fixed instances 100..103, or not)."""
    games = [PettingZooGame("dqn_transfer.envs.lbf:parallel_env", kwargs, 100 + r if fixed else None) for r in range(4)]
    rngs = [np.random.default_rng([seed, r]) for r in range(4)]
    for game, rng in zip(games, rngs):
        game.reset(rng)
    return games, rngs


@pytest.mark.parametrize("fixed", [True, False], ids=["fixed_start", "drawn_starts"])
@pytest.mark.parametrize("game", BATCHES)
def test_a_batch_of_lbf_games_steps_as_lbforaging_steps_each(game, fixed):
    looped = LoopedGames(*lbf_games(BATCHES[game], fixed, seed=3))
    batch = game_batch(*lbf_games(BATCHES[game], fixed, seed=3))
    assert isinstance(batch, ForagingBatch)
    rng = np.random.default_rng(11)
    loaded = failed = endings = 0
    for step in range(700):
        assert np.array_equal(batch.obs, looped.obs) and np.array_equal(batch.live, looped.live)
        if step % 50 == 7:  # a checkpoint's episode, saved and continued in the one-game format
            for r in range(4):
                assert batch.state_dict(r) == looped.state_dict(r)
            batch.load_state_dict(2, looped.state_dict(2))
        actions = rng.integers(0, 6, size=(4, looped.num_agents))
        actions[rng.random(actions.shape) < 0.3] = 5  # LOAD more often than a uniform draw would
        ours, theirs = batch.step(actions), looped.step(actions)
        for name, mine, expected in zip(ours._fields, ours, theirs):
            assert mine.dtype == expected.dtype and np.array_equal(mine, expected), (step, name)
        loaded += int((theirs.rewards > 0).sum())
        failed += int((theirs.rewards < 0).sum())
        endings += int(theirs.episode_end.sum())
        batch.reset(theirs.episode_end)
        looped.reset(theirs.episode_end)
    assert loaded >= 10 and endings > 20  # food loaded (rarely where it needs every player) and episodes ended
    if BATCHES[game].get("penalty"):
        assert failed > 0


def test_other_games_or_a_drawing_game_are_not_batched_as_lbf():
    kwargs = BATCHES["the_studys_task"]
    games, rngs = lbf_games(kwargs, True, seed=0)
    other, _ = lbf_games({**kwargs, "penalty": 0.5}, True, seed=0)
    assert isinstance(game_batch(games[:2] + other[:2], rngs), LoopedGames)
    drawing, _ = lbf_games({**kwargs, "render_mode": "rgb_array"}, True, seed=0)
    assert isinstance(game_batch(drawing, rngs), LoopedGames)
