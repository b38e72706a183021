"""The treasure hunt's observation code: ids worked out by hand, and a bijection on what the game plays."""

import numpy as np
import pytest

from dqn_transfer.envs.game import TreasureHuntGame, make_game
from dqn_transfer.envs.observation_code import observation_code

# 3x3, one chest at (0, 2), a trap at (2, 0), agent 0 at (0, 0), agent 1 at (2, 2).
LAYOUT = "0.T\n...\nX.1"


def played_observations(game: TreasureHuntGame, steps: int, seed: int) -> np.ndarray:
    """Every observation of ``steps`` random joint moves (resets included), ``[N, D]``."""
    rng = np.random.default_rng(seed)
    seen = [game.reset(rng)]
    for _ in range(steps):
        seen.append(game.step(rng.integers(0, game.num_actions, game.num_agents)).obs)
        if game.done:
            seen.append(game.reset(rng))
    return np.concatenate(seen)


@pytest.mark.parametrize(
    ("mode", "expected_ids", "num_ids"),
    [
        # id = cell * 2 + belief (the chest full: 1); 9 cells * 2
        ("cooperative", [0 * 2 + 1, 8 * 2 + 1], 18),
        # id = (cell * 2 + belief) * 2 + assignment; agent 0 takes the chest (both 2 moves away, the lower
        # index wins), agent 1 has none
        ("deliberative", [(0 * 2 + 1) * 2 + 1, (8 * 2 + 1) * 2 + 0], 36),
    ],
)
def test_ids_of_the_first_observations_worked_by_hand(mode, expected_ids, num_ids):
    game = make_game(layout=LAYOUT, mode=mode)
    code = observation_code([game])
    assert code is not None and code.num_ids == num_ids
    obs = game.reset(np.random.default_rng(0))
    assert code.encode(obs, np.zeros(2, dtype=np.int64)).tolist() == expected_ids


SETTINGS = [
    {"mode": "competitive"},
    {"mode": "cooperative", "obs_encoding": "coords"},
    {"mode": "deliberative"},
    {"mode": "deliberative", "obs_encoding": "coords", "view_radius": 1},
    {"mode": "competitive", "view_radius": 2},
    {"mode": "cooperative", "view_radius": 1},
]


@pytest.mark.parametrize("settings", SETTINGS)
@pytest.mark.parametrize("single_agent", [False, True])
def test_the_code_is_a_bijection_on_the_observations_the_game_plays(settings, single_agent):
    """decode(encode(obs)) == obs for played observations, encode(decode(id)) == id for every id; the
    single-agent game has no treasures segment, so its beliefs come from the view's chest plane."""
    game = make_game(size=6, num_treasures=3, num_traps=2, num_agents=3, complexity=0.1, map_seed=4, **settings)
    if single_agent:
        game = game.single_agent_game()
    code = observation_code([game])
    assert code is not None
    obs = played_observations(game, 1500, seed=1)
    ids = code.encode(obs, np.zeros(len(obs), dtype=np.int64))
    assert (ids >= 0).all() and ids.max() < code.num_ids
    np.testing.assert_array_equal(code.decode(0, ids), obs)
    every = np.arange(code.num_ids)
    decoded = code.decode(0, every)
    again = code.encode(decoded, np.zeros(code.num_ids, dtype=np.int64))
    if single_agent and settings.get("view_radius", 0) == 0:
        assert code.num_ids == 36  # the cell alone: nothing shows a chest
    if not single_agent or settings.get("view_radius", 0) == 0:
        np.testing.assert_array_equal(again, every)
    else:  # an id believing a chest out of sight full decodes to the one believing it empty
        assert np.array_equal(code.decode(0, again), decoded) and (again <= every).all()
    assert len(np.unique(decoded, axis=0)) == len(np.unique(again))


def test_replicas_on_different_maps_decode_their_own_view_and_refuse_the_others():
    games = [
        make_game(size=6, num_treasures=3, num_traps=2, num_agents=3, view_radius=1, map_seed=seed) for seed in (0, 1)
    ]
    code = observation_code(games)
    assert code is not None
    for replica, game in enumerate(games):
        obs = played_observations(game, 300, seed=replica)
        ids = code.encode(obs, np.full(len(obs), replica))
        np.testing.assert_array_equal(code.decode(replica, ids), obs)
        # Another map's window around some played cell differs: there it is no observation.
        assert (code.encode(obs, np.full(len(obs), 1 - replica)) < 0).any()


def test_vectors_that_are_no_observation_get_minus_one():
    game = make_game(layout=LAYOUT)
    code = observation_code([game])
    assert code is not None
    obs = game.reset(np.random.default_rng(0))[:1]
    two_cells = obs.copy()
    two_cells[0, 4] = 1.0
    half_belief = obs.copy()
    half_belief[0, -1] = 0.5
    nowhere = np.zeros_like(obs)
    assert code.encode(
        np.concatenate([obs, two_cells, half_belief, nowhere]), np.zeros(4, dtype=np.int64)
    ).tolist() == [
        1,
        -1,
        -1,
        -1,
    ]


def test_games_without_one_code_get_none():
    small, large = make_game(size=6, num_treasures=3, num_traps=2), make_game(size=7, num_treasures=3, num_traps=2)
    assert observation_code([small, large]) is None  # another map size: another observation
    assert observation_code([small, make_game(size=6, num_treasures=3, num_traps=2, view_radius=1)]) is None
