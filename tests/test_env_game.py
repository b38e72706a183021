"""Hand-computed episodes of the treasure-hunt game (rules: docs/game.md).

Actions: 0 up, 1 down, 2 left, 3 right. Rows and cols count from 0; position index = row * n + col.
Every expected value below is worked out from the rules, not read off the code.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dqn_transfer.envs.game import TreasureHuntGame, assign_agents
from dqn_transfer.envs.maps import parse_layout
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
    rewards = [float(s[1][0]) for s in steps]
    assert rewards == [-1.0, -1.0, -1.0, 100.0]  # 3 x -1 + 100 = 97
    assert [bool(s[2][0]) for s in steps] == [False, False, False, True]
    assert not any(bool(s[3][0]) for s in steps)
    assert steps[-1][4]["treasures_collected"] == 1 and game.treasures_collected == 1
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
    assert [float(s[1][0]) for s in steps] == [-1.0] * 4
    # (0,0) -right-> (0,1) -down-> (1,1) '#': home again
    steps = play(game, [RIGHT], [DOWN])
    assert [int(np.flatnonzero(s[0][0, :25])[0]) for s in steps] == [1, 0]
    assert game.positions.tolist() == [[0, 0]]


TRAP_MAP = """
0.X
...
T..
"""


def test_trap_costs_100_and_terminates():
    game, _ = make(TRAP_MAP)
    (o1, r1, t1, u1, i1), (o2, r2, t2, u2, i2) = play(game, [RIGHT], [RIGHT])
    assert float(r1[0]) == -1.0 and not t1[0] and not i1["trap"][0]
    assert float(r2[0]) == -100.0 and t2[0] and not u2[0] and i2["trap"][0]
    assert not i2["live"][0] and game.done
    assert o2[0, 2] == 1.0  # the final observation is the trap cell (0, 2)


def test_truncation_exactly_at_n_squared_moves():
    game, _ = make(TRAP_MAP)  # 3 x 3: max_steps = 9
    for move in range(1, 10):
        _, reward, terminated, truncated, _ = game.step(np.array([UP]))  # off grid: stays
        assert float(reward[0]) == -1.0 and not terminated[0]
        assert bool(truncated[0]) == (move == 9), move
    assert game.done
    game, _ = make(TRAP_MAP, max_steps=2)
    assert [bool(s[3][0]) for s in play(game, [UP], [UP])] == [False, True]


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
    obs, reward, terminated, _, info = game.step(np.array([RIGHT, DOWN]))
    assert reward.tolist() == [100.0, -1.0] and terminated.tolist() == [True, False]
    assert info["treasures_collected"] == 1 and info["live"].tolist() == [False, True]
    # B's treasures segment: competitive -> still believes full; cooperative -> announced
    assert obs[1, 9] == (1.0 if mode == "competitive" else 0.0)
    assert obs[0, 9] == 0.0
    # step 2: B up to (0, 2); step 3: B left into the empty chest: -1, the game goes on
    obs, reward, terminated, _, _ = game.step(np.array([RIGHT, UP]))
    assert reward.tolist() == [0.0, -1.0]  # a finished agent gets 0, its action is ignored
    obs, reward, terminated, truncated, info = game.step(np.array([RIGHT, LEFT]))
    assert reward.tolist() == [0.0, -1.0] and not terminated[1] and not truncated[1]
    assert info["treasures_collected"] == 0 and info["live"].tolist() == [False, True]
    assert obs[1, 1] == 1.0 and obs[1, 9] == 0.0  # on the chest cell; now knows it is empty
    assert obs[0, 1] == 1.0  # A keeps its last observation


def test_tie_on_a_full_chest_has_one_winner_drawn_by_the_rng():
    winners = []
    for seed in range(40):
        game, _ = make(TWO_AGENTS, seed=seed)
        obs, reward, terminated, _, info = game.step(np.array([RIGHT, LEFT]))  # both enter (0,1)
        assert sorted(reward.tolist()) == [-1.0, 100.0]
        assert terminated.sum() == 1 and info["treasures_collected"] == 1
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
    _, reward, _, _, _ = game.step(np.array([RIGHT, DOWN]))
    assert reward.tolist() == [99.0, 99.0]  # 100 + (-1), for both
    _, reward, _, _, _ = game.step(np.array([RIGHT, DOWN]))
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
def test_assign_agents_hand_matrices():
    # greedy (cheapest pair first: agent 0 -> chest 0 at 1, then agent 1 -> chest 1 at 10) = 11;
    # optimal: agent 0 -> chest 1 (2) + agent 1 -> chest 0 (2) = 4
    assert assign_agents(np.array([[1, 2], [2, 10]])).tolist() == [1, 0]
    assert assign_agents(np.array([[2], [2]])).tolist() == [0, -1]  # tie: lower index wins
    assert assign_agents(np.array([[5], [1]])).tolist() == [-1, 0]
    assert assign_agents(np.array([[3, 3], [3, 3]])).tolist() == [0, 1]
    assert assign_agents(np.array([[1, 1], [1, 5]])).tolist() == [1, 0]  # optimum before ties
    assert assign_agents(np.array([[2, 2], [2, 2], [2, 2]])).tolist() == [0, 1, -1]
    assert assign_agents(np.array([[4, 1, 1], [1, 4, 4]])).tolist() == [1, 0]


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
    obs, reward, terminated, _, _ = game.step(np.array([RIGHT, UP]))
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
    obs, reward, terminated, _, info = game.step(np.array([DOWN, UP]))  # agent 0 into (3,0) trap
    assert reward.tolist() == [-100.0, -1.0] and info["trap"].tolist() == [True, False]
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


def test_assign_agents_matches_brute_force_on_tie_heavy_matrices():
    rng = np.random.default_rng(0)
    for _ in range(400):
        cost = rng.integers(0, 3, size=(rng.integers(1, 5), rng.integers(1, 5)))
        assert assign_agents(cost).tolist() == _brute_force_assignment(cost), cost
