"""Level-Based Foraging's faster observations and valid actions (``envs/lbf.FastForagingEnv``) against
lbforaging's own ``ForagingEnv``: both are played side by side from the same seed with the same random
actions, and every vector, valid-action list, reward and ending must be the same."""

from __future__ import annotations

import numpy as np
import pytest
from lbforaging.foraging.environment import ForagingEnv

from dqn_transfer.envs.lbf import FastForagingEnv

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
