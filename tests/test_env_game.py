"""Hand-computed episodes of the treasure-hunt game (rules: docs/game.md).

Actions: 0 up, 1 down, 2 left, 3 right. Rows and cols count from 0; position index = row * n + col.
Every expected value below is worked out from the rules, not read off the code.
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.maps import parse_layout
from dqn_transfer.envs.rules import best_assignment
from dqn_transfer.envs.treasure_hunt import parallel_env

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3

CORRIDOR = """
0...T
.####
.....
####.
.....
"""


def make(layout: str, seed: int = 0, **kwargs) -> tuple[TreasureHuntGame, np.ndarray]:
    game = TreasureHuntGame(parse_layout(layout), **kwargs)
    return game, game.reset(np.random.default_rng(seed))


def play(game: TreasureHuntGame, *joint_actions):
    """Step through joint actions; returns the per-step outputs."""
    return [game.step(np.array(a)) for a in joint_actions]


def test_corridor_to_treasure_returns_97():
    game, obs = make(CORRIDOR)
    assert obs.shape == (1, 25 + 1) and obs[0, 0] == 1.0 and obs[0, 25] == 1.0
    steps = play(game, [RIGHT], [RIGHT], [RIGHT], [RIGHT])
    rewards = [float(s.rewards[0]) for s in steps]
    assert rewards == [-1.0, -1.0, -1.0, 100.0]  # 3 x -1 + 100 = 97
    assert [bool(s.terminated[0]) for s in steps] == [False, False, False, True]
    assert not any(bool(s.truncated[0]) for s in steps)
    assert steps[-1].treasures_collected == 1 and game.treasures_collected == 1
    assert game.done and not game.chest_full[0]
    last_obs = steps[-1][0][0]
    assert last_obs[4] == 1.0 and last_obs[:25].sum() == 1.0  # on (0, 4): index 4
    assert last_obs[25] == 0.0  # it emptied the chest
    with pytest.raises(RuntimeError, match="reset"):
        game.step(np.array([RIGHT]))


def test_obstacle_sends_home_and_off_grid_stays():
    game, _ = make(CORRIDOR)
    # (0,0) -up-> off grid: stay; -left-> stay; -down-> (1,0); -right-> (1,1) is '#': home (0,0)
    steps = play(game, [UP], [LEFT], [DOWN], [RIGHT])
    positions = [int(np.flatnonzero(s[0][0, :25])[0]) for s in steps]
    assert positions == [0, 0, 5, 0]
    assert [float(s.rewards[0]) for s in steps] == [-1.0] * 4
    assert [bool(s.bounced[0]) for s in steps] == [False, False, False, True]  # off-grid is no bounce
    # (0,0) -right-> (0,1) -down-> (1,1) '#': home again
    steps = play(game, [RIGHT], [DOWN])
    assert [int(np.flatnonzero(s[0][0, :25])[0]) for s in steps] == [1, 0]
    assert [s.info["bounced"].tolist() for s in steps] == [[False], [True]]
    assert game.positions.tolist() == [[0, 0]]


TRAP_MAP = """
0.X
...
T..
"""


def test_trap_costs_100_and_terminates():
    game, _ = make(TRAP_MAP)
    first, second = play(game, [RIGHT], [RIGHT])
    assert float(first.rewards[0]) == -1.0 and not first.terminated[0] and not first.trap[0]
    assert float(second.rewards[0]) == -100.0 and second.terminated[0] and not second.truncated[0] and second.trap[0]
    assert not second.live[0] and game.done
    assert second.obs[0, 2] == 1.0  # the final observation is the trap cell (0, 2)


def test_truncation_exactly_at_n_squared_moves():
    game, _ = make(TRAP_MAP)  # 3 x 3: max_steps = 9
    for move in range(1, 10):
        _, reward, terminated, truncated, *_ = game.step(np.array([UP]))  # off grid: stays
        assert float(reward[0]) == -1.0 and not terminated[0]
        assert bool(truncated[0]) == (move == 9), move
    assert game.done
    game, _ = make(TRAP_MAP, max_steps=2)
    assert [bool(s.truncated[0]) for s in play(game, [UP], [UP])] == [False, True]


def test_treasure_on_the_last_move_terminates_instead_of_truncating():
    game, _ = make(CORRIDOR, max_steps=4)
    steps = play(game, [RIGHT], [RIGHT], [RIGHT], [RIGHT])
    assert float(steps[-1][1][0]) == 100.0 and steps[-1][2][0] and not steps[-1][3][0]


TWO_AGENTS = """
0T1
...
...
"""


@pytest.mark.parametrize("mode", ["competitive", "cooperative"])
def test_empty_chest_and_what_the_other_agent_knows(mode):
    game, obs = make(TWO_AGENTS, mode=mode)
    assert game.obs_layout() == [("position", 9), ("treasures", 1)]
    # step 1: A (agent 0) takes the chest at (0, 1); B (agent 1) steps down to (1, 2)
    obs, reward, terminated, _, *_ = outcome = game.step(np.array([RIGHT, DOWN]))
    assert reward.tolist() == [100.0, -1.0] and terminated.tolist() == [True, False]
    assert outcome.info["treasures_collected"] == 1 and outcome.info["live"].tolist() == [False, True]
    # B's treasures segment: competitive -> still believes full; cooperative -> announced
    assert obs[1, 9] == (1.0 if mode == "competitive" else 0.0)
    assert obs[0, 9] == 0.0
    # step 2: B up to (0, 2); step 3: B left into the empty chest: -1, the game goes on
    obs, reward, terminated, _, *_ = game.step(np.array([RIGHT, UP]))
    assert reward.tolist() == [0.0, -1.0]  # a finished agent gets 0, its action is ignored
    obs, reward, terminated, truncated, *_ = outcome = game.step(np.array([RIGHT, LEFT]))
    assert reward.tolist() == [0.0, -1.0] and not terminated[1] and not truncated[1]
    assert outcome.info["treasures_collected"] == 0 and outcome.info["live"].tolist() == [False, True]
    assert obs[1, 1] == 1.0 and obs[1, 9] == 0.0  # on the chest cell; now knows it is empty
    assert obs[0, 1] == 1.0  # A keeps its last observation


def test_tie_on_a_full_chest_has_one_winner_drawn_by_the_rng():
    winners = []
    for seed in range(40):
        game, _ = make(TWO_AGENTS, seed=seed)
        obs, reward, terminated, _, *_ = outcome = game.step(np.array([RIGHT, LEFT]))  # both enter (0,1)
        assert sorted(reward.tolist()) == [-1.0, 100.0]
        assert terminated.sum() == 1 and outcome.info["treasures_collected"] == 1
        winner = int(np.flatnonzero(terminated)[0])
        loser = 1 - winner
        assert obs[loser, 9] == 0.0  # competitive: the loser learned the chest is empty
        assert game.positions[loser].tolist() == [0, 1]
        winners.append(winner)
        again, _ = make(TWO_AGENTS, seed=seed)  # same seed, same winner
        assert again.step(np.array([RIGHT, LEFT]))[2][winner]
    assert set(winners) == {0, 1}


def test_team_reward_is_the_sum_for_agents_live_before_the_step():
    game, _ = make(TWO_AGENTS, reward_mode="team")
    _, reward, _, _, *_ = game.step(np.array([RIGHT, DOWN]))
    assert reward.tolist() == [99.0, 99.0]  # 100 + (-1), for both
    _, reward, _, _, *_ = game.step(np.array([RIGHT, DOWN]))
    assert reward.tolist() == [0.0, -1.0]  # only B was live: the sum is its -1; A gets 0


def test_obs_layout_sizes_position_index_and_coords():
    layout = "T...T\n.....\n..0..\n.....\n.1..X"
    game, obs = make(layout)
    assert game.obs_layout() == [("position", 25), ("treasures", 2)] and game.obs_dim == 27
    assert np.flatnonzero(obs[0, :25]).tolist() == [12]  # (2, 2): 2 * 5 + 2
    assert np.flatnonzero(obs[1, :25]).tolist() == [21]  # (4, 1): 4 * 5 + 1
    assert obs[:, 25:].tolist() == [[1.0, 1.0], [1.0, 1.0]]
    obs = game.step(np.array([RIGHT, UP]))[0]
    assert np.flatnonzero(obs[0, :25]).tolist() == [13]  # (2, 3)
    assert np.flatnonzero(obs[1, :25]).tolist() == [16]  # (3, 1)
    game, obs = make(layout, obs_encoding="coords", mode="deliberative", view_radius=2)
    assert game.obs_layout() == [("position", 2), ("treasures", 2), ("assignment", 2), ("view", 75)]
    assert obs.shape == (2, 81) and obs.dtype == np.float32
    assert obs[0, :2].tolist() == [0.5, 0.5] and obs[1, :2].tolist() == [1.0, 0.25]  # /(n-1)=4


VIEW_MAP = """
#0..
1T..
....
..X.
"""


@pytest.mark.parametrize("mode", ["competitive", "cooperative"])
def test_view_window_planes(mode):
    game, obs = make(VIEW_MAP, view_radius=1, mode=mode)
    lo = 16 + 1  # position (16) + treasures (1)
    obstacle, trap, chest = obs[0, lo : lo + 9], obs[0, lo + 9 : lo + 18], obs[0, lo + 18 :]
    # agent 0 at (0, 1): window rows -1..1, cols 0..2, row-major
    assert obstacle.tolist() == [1, 1, 1, 1, 0, 0, 0, 0, 0]  # off-grid row, then '#' at (0,0)
    assert trap.tolist() == [0] * 9
    assert chest.tolist() == [0, 0, 0, 0, 0, 0, 0, 1, 0]  # chest (1,1) is below the agent
    # agent 1 takes the chest; agent 0 walks (0,2) -> (1,2) -> (2,2)
    game.step(np.array([RIGHT, RIGHT]))
    game.step(np.array([DOWN, UP]))
    obs = game.step(np.array([DOWN, UP]))[0]
    obstacle, trap, chest = obs[0, lo : lo + 9], obs[0, lo + 9 : lo + 18], obs[0, lo + 18 :]
    # around (2,2): rows 1..3, cols 1..3; the trap (3,2) is bottom-middle, the chest top-left
    assert obstacle.tolist() == [0] * 9
    assert trap.tolist() == [0, 0, 0, 0, 0, 0, 0, 1, 0]
    believed = 1.0 if mode == "competitive" else 0.0  # seeing a chest does not reveal it
    assert chest.tolist() == [believed] + [0] * 8
    assert obs[0, 16] == believed


# ---------------------------------------------------------------- deliberative coordinator
def assign(cost: np.ndarray) -> np.ndarray:
    return best_assignment(cost.astype(np.int64))


def test_the_coordinators_assignment_on_hand_matrices():
    # greedy (cheapest pair first: agent 0 -> chest 0 at 1, then agent 1 -> chest 1 at 10) = 11;
    # optimal: agent 0 -> chest 1 (2) + agent 1 -> chest 0 (2) = 4
    assert assign(np.array([[1, 2], [2, 10]])).tolist() == [1, 0]
    assert assign(np.array([[2], [2]])).tolist() == [0, -1]  # tie: lower index wins
    assert assign(np.array([[5], [1]])).tolist() == [-1, 0]
    assert assign(np.array([[3, 3], [3, 3]])).tolist() == [0, 1]
    assert assign(np.array([[1, 1], [1, 5]])).tolist() == [1, 0]  # optimum before ties
    assert assign(np.array([[2, 2], [2, 2], [2, 2]])).tolist() == [0, 1, -1]
    assert assign(np.array([[4, 1, 1], [1, 4, 4]])).tolist() == [1, 0]


# chest 0 at (0,0), chest 1 at (0,3); agent 0 at (0,2), agent 1 at (0,5); open grid: Manhattan
#   d(a0, c0) = 2, d(a0, c1) = 1, d(a1, c0) = 5, d(a1, c1) = 2
#   greedy (a0 takes its nearest c1, a1 gets c0): 1 + 5 = 6; optimal a0->c0, a1->c1: 2 + 2 = 4
DELIBERATIVE = """
T.0T.1
......
......
......
......
......
"""


def test_deliberative_assignment_is_optimal_not_greedy_and_reassigns():
    game, obs = make(DELIBERATIVE, mode="deliberative")
    assert game.obs_layout() == [("position", 36), ("treasures", 2), ("assignment", 2)]
    assert obs[:, 36:38].tolist() == [[1, 1], [1, 1]]
    assert obs[:, 38:40].tolist() == [[1, 0], [0, 1]]
    # agent 0 ignores its assignment and takes chest 1 next to it; agent 1 bumps the top edge
    obs, reward, terminated, _, *_ = game.step(np.array([RIGHT, UP]))
    assert reward.tolist() == [100.0, -1.0] and terminated.tolist() == [True, False]
    assert obs[1, 36:38].tolist() == [1, 0]  # truth: chest 1 is empty
    assert obs[1, 38:40].tolist() == [1, 0]  # reassigned: agent 1 -> chest 0
    assert obs[0, 38:40].tolist() == [1, 0]  # the finished agent keeps its last assignment
    assert game.assignment.tolist() == [0, 0]


def test_deliberative_more_agents_than_chests_and_tie_to_lower_index():
    # chest (1,1) is 2 steps from both agent 0 (0,0) and agent 1 (0,2): the tie goes to agent 0
    game, obs = make("0.1\n.T.\n...", mode="deliberative")
    assert obs[:, 10].tolist() == [1.0, 0.0]  # assignment segment after position(9)+treasures(1)
    # agent 1 one step closer -> it gets the chest and agent 0 none
    game, obs = make("0..\n.T1\n...", mode="deliberative")
    assert obs[:, 10].tolist() == [0.0, 1.0]


def test_deliberative_reassigns_when_an_agent_dies_in_a_trap():
    # agent 0 (0,0) and agent 1 (0,4); chest at (4,2): d = 6 for both -> agent 0 (tie)
    layout = "0...1\n.....\n.....\nX....\n..T.."
    game, obs = make(layout, mode="deliberative")
    assert obs[:, 26].tolist() == [1.0, 0.0]
    game.step(np.array([DOWN, UP]))
    game.step(np.array([DOWN, UP]))
    obs, reward, terminated, _, *_ = outcome = game.step(np.array([DOWN, UP]))  # agent 0 into (3,0) trap
    assert reward.tolist() == [-100.0, -1.0] and outcome.info["trap"].tolist() == [True, False]
    assert obs[1, 26] == 1.0  # the chest now goes to agent 1


# ---------------------------------------------------------------- the PettingZoo face on a hand map
def test_parallel_env_hand_episode_and_render():
    env = parallel_env(layout=TWO_AGENTS, mode="cooperative", render_mode="ansi")
    obs, infos = env.reset(seed=0)
    assert env.agents == ["agent_0", "agent_1"] and set(infos) == {"agent_0", "agent_1"}
    assert env.obs_layout("agent_0") == [("position", 9), ("treasures", 1)]
    assert env.render() == "0T1\n...\n...\nstep 0/9  live agents: [0, 1]  full chests: 1/1"
    obs, rew, term, trunc, _ = env.step({"agent_0": RIGHT, "agent_1": DOWN})
    assert rew == {"agent_0": 100.0, "agent_1": -1.0}
    assert term == {"agent_0": True, "agent_1": False} and env.agents == ["agent_1"]
    assert obs["agent_1"][9] == 0.0
    assert env.render().splitlines()[:2] == [".t.", "..1"]
    for _ in range(8):  # steps 2..9: the 9th (= n * n) move truncates
        _, rew, term, trunc, _ = env.step({"agent_1": DOWN})
    assert set(rew) == {"agent_1"} and trunc == {"agent_1": True} and env.agents == []


def test_rgb_render_draws_cells_and_agents():
    env = parallel_env(layout=TRAP_MAP, render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (48, 48, 3) and img.dtype == np.uint8
    agent, chest, trap, free = img[8, 8], img[40, 8], img[8, 40], img[24, 24]
    assert len({tuple(agent), tuple(chest), tuple(trap), tuple(free)}) == 4
    env.step({"agent_0": DOWN})
    assert tuple(env.render()[8, 8]) == tuple(free)  # the agent left (0,0)


def _brute_force_assignment(cost: np.ndarray) -> list[int]:
    """Every maximum assignment; keep the minimum total, then the agent-by-agent preference
    (a chest before none; nearer chest; lower chest number) in agent index order."""
    num_agents, num_chests = cost.shape
    candidates = []
    for assignment in itertools.product([*range(num_chests), -1], repeat=num_agents):
        used = [c for c in assignment if c >= 0]
        if len(used) != len(set(used)) or len(used) != min(num_agents, num_chests):
            continue
        total = sum(cost[a, c] for a, c in enumerate(assignment) if c >= 0)
        preference = [(0, cost[a, c], c) if c >= 0 else (1, 0, 0) for a, c in enumerate(assignment)]
        candidates.append((total, preference, list(assignment)))
    return min(candidates)[2]


def test_the_coordinators_assignment_matches_brute_force_on_tie_heavy_matrices():
    rng = np.random.default_rng(0)
    for _ in range(600):
        high = int(rng.choice([2, 3, 50]))  # few distinct costs: ties everywhere; many: pruning matters
        cost = rng.integers(0, high, size=(rng.integers(1, 6), rng.integers(1, 6)))
        assert assign(cost).tolist() == _brute_force_assignment(cost), cost


# ---------------------------------------------------------------- saving and restoring an episode
# 4 agents, 3 chests, 2 traps, 2 obstacles; agents 0/1 and 2/3 flank a chest each, so ties (drawn
# by the generator) are frequent under random actions.
SAVE_MAP = """
0T1.X.
..#...
2T3...
......
.#...X
...T..
"""


def _rollout(game: TreasureHuntGame, rng: np.random.Generator, actions: np.ndarray) -> list:
    """Step through ``actions``, resetting with ``rng`` whenever the episode is over."""
    out = []
    for joint in actions:
        if game.done:
            out.append(("reset", game.reset(rng)))
        obs, reward, terminated, truncated, *_ = outcome = game.step(joint)
        out.append(
            (
                obs,
                reward,
                terminated,
                truncated,
                game.live,
                outcome.info["treasures_collected"],
                outcome.info["trap"],
                outcome.info["live"],
            )
        )
    return out


def _assert_same(got: list, expected: list) -> None:
    assert len(got) == len(expected)
    for step, (a, b) in enumerate(zip(got, expected)):
        assert len(a) == len(b), step
        for x, y in zip(a, b):
            if isinstance(x, np.ndarray):
                assert x.dtype == y.dtype and np.array_equal(x, y), step
                assert x.tobytes() == y.tobytes(), step  # bit-exact, not just equal values
            else:
                assert x == y, step


@pytest.mark.parametrize(
    "mode, obs_encoding, view_radius, max_steps",
    [
        ("competitive", "onehot", 0, None),
        ("competitive", "coords", 1, 8),
        ("cooperative", "coords", 0, 8),
        ("cooperative", "onehot", 0, None),
        ("deliberative", "onehot", 0, 8),
        ("deliberative", "coords", 2, None),
    ],
)
def test_state_dict_round_trip_mid_episode_replays_identically(mode, obs_encoding, view_radius, max_steps):
    settings = dict(mode=mode, obs_encoding=obs_encoding, view_radius=view_radius, max_steps=max_steps)
    actions = np.random.default_rng(1).integers(0, 4, size=(400, 4))
    game = TreasureHuntGame(parse_layout(SAVE_MAP), **settings)
    rng = np.random.default_rng(7)
    obs = game.reset(rng)
    # Warm up until mid-episode: some agent done, some still live, a step or more in.
    for step, joint in enumerate(actions[:100]):  # noqa: B007 (step is read after the loop)
        if game.steps >= 2 and 0 < game.live.sum() < 4:
            break
        if game.done:
            obs = game.reset(rng)
        obs = game.step(joint)[0]
    else:
        pytest.fail("no mid-episode save point in the warm-up")
    saved_text = json.dumps(game.state_dict())  # as a checkpoint would store it
    saved_rng = rng.bit_generator.state
    at_save = (obs, game.positions, game.live, game.chest_full, game.assignment, game.steps, game.treasures_collected)
    expected = _rollout(game, rng, actions[step:])
    assert sum(isinstance(out[0], str) for out in expected) >= 3  # several episodes follow
    assert rng.bit_generator.state != saved_rng  # chest ties were drawn after the save

    fresh = TreasureHuntGame(parse_layout(SAVE_MAP), **settings)  # never reset
    restored_rng = np.random.default_rng()
    restored_rng.bit_generator.state = saved_rng
    obs = fresh.load_state_dict(json.loads(saved_text), restored_rng)
    restored = (
        obs,
        fresh.positions,
        fresh.live,
        fresh.chest_full,
        fresh.assignment,
        fresh.steps,
        fresh.treasures_collected,
    )
    _assert_same([restored], [at_save])
    _assert_same(_rollout(fresh, restored_rng, actions[step:]), expected)
    assert restored_rng.bit_generator.state == rng.bit_generator.state


def _plain(value) -> bool:
    """Only the JSON types: lists, ints, floats, bools (no numpy scalars)."""
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return type(value) in (int, float, bool)


def test_state_dict_hand_values_survive_json():
    game, _ = make(TWO_AGENTS)
    game.step(np.array([RIGHT, DOWN]))  # A takes the chest at (0,1) = 1; B to (1,2) = 5
    state = game.state_dict()
    assert state == {
        "pos": [1, 5],
        "live": [False, True],
        "chest_full": [False],
        "belief": [[0.0], [1.0]],  # competitive: B still believes the chest full
        "assigned": [-1, -1],
        "obs": [[0, 1, 0, 0, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 1, 0, 0, 0, 1]],
        "t": 1,
        "treasures_collected": 1,
    }
    assert all(_plain(v) for v in state.values())
    assert json.loads(json.dumps(state)) == state

    # coords on a 4 x 4 map divide by 3: float32(1/3) is not the double 1/3, yet comes back exactly
    game, obs = make(VIEW_MAP, obs_encoding="coords", view_radius=1)
    third = float(np.float32(1 / 3))
    assert third != 1 / 3
    state = json.loads(json.dumps(game.state_dict()))
    assert state["obs"][0][:2] == [0.0, third] and state["obs"][1][:2] == [third, 0.0]
    fresh = TreasureHuntGame(parse_layout(VIEW_MAP), obs_encoding="coords", view_radius=1)
    restored = fresh.load_state_dict(state, np.random.default_rng(0))
    assert restored.dtype == np.float32 and restored.tobytes() == obs.tobytes()


# chest (0,1) between the agents, an obstacle at (1,1) = cell 4, a trap at (2,2)
GUARDED = "0T1\n.#.\n..X"


def test_load_state_dict_rejects_another_games_state_and_changes_nothing():
    def state_of(layout=GUARDED, actions=None, **settings):
        game = TreasureHuntGame(parse_layout(layout), **settings)
        game.reset(np.random.default_rng(0))
        if actions is not None:
            game.step(np.array(actions))
        return game.state_dict()

    moved = state_of(actions=[DOWN, DOWN])  # a valid state of this game: agents at cells 3 and 5
    bad = [  # onehot obs_dim here: 9 cells + 1 chest = 10
        (state_of(num_agents=1), r"'pos' has shape \(1,\), expected \(2,\).*2 agents"),
        (state_of("0T1\n.#.\nT.X"), r"'chest_full' has shape \(2,\), expected \(1,\).*1 chests"),
        (state_of(obs_encoding="coords"), r"'obs' has shape \(2, 3\), expected \(2, 10\)"),
        (state_of(view_radius=1), r"'obs' has shape \(2, 37\), expected \(2, 10\)"),  # 10 + 27
        ({**moved, "pos": [9, 5]}, r"agent 0 at cell 9, outside the 3 x 3 grid"),
        ({**moved, "pos": [3, 4]}, r"agent 1 on an obstacle"),
        ({**moved, "obs": moved["obs"][:1]}, r"'obs' has shape \(1, 10\)"),  # checked last
        ({**moved, "t": 10}, r"'t' must be an integer in 0..9"),
        ({k: v for k, v in moved.items() if k != "t"}, r"missing \['t'\]"),
    ]
    winners = set()
    for seed in range(12):
        game, _ = make(GUARDED, seed=seed)
        twin, _ = make(GUARDED, seed=seed)
        before = game.state_dict()
        for state, message in bad:
            with pytest.raises(ValueError, match=message):
                game.load_state_dict(state, np.random.default_rng(999))
            assert game.state_dict() == before
        # both enter the chest: the tie is still drawn by the game's own generator, not seed 999's
        got, expected = play(game, [RIGHT, LEFT]), play(twin, [RIGHT, LEFT])
        _assert_same([got[0][:4]], [expected[0][:4]])
        winners.add(int(np.flatnonzero(got[0][2])[0]))
    assert winners == {0, 1}


def test_load_state_dict_draws_later_ties_with_the_given_generator():
    winners = set()
    for seed in range(12):
        game = TreasureHuntGame(parse_layout(GUARDED))
        rng = np.random.default_rng(seed)
        game.reset(rng)
        play(game, [DOWN, DOWN], [UP, UP])  # mid-episode (t = 2), both back beside the chest
        saved, saved_rng = game.state_dict(), rng.bit_generator.state
        expected = play(game, [RIGHT, LEFT])  # both enter the full chest: a tie
        fresh = TreasureHuntGame(parse_layout(GUARDED))
        restored_rng = np.random.default_rng()
        restored_rng.bit_generator.state = saved_rng
        fresh.load_state_dict(saved, restored_rng)
        got = play(fresh, [RIGHT, LEFT])
        _assert_same([got[0][:4]], [expected[0][:4]])
        assert restored_rng.bit_generator.state == rng.bit_generator.state
        winners.add(int(np.flatnonzero(got[0][2])[0]))
    assert winners == {0, 1}  # so a generator other than the given one would be caught
