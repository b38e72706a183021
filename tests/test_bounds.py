"""The scripted reference teams (evaluation/bounds.py) on hand-worked maps.

Every expected value is worked out by hand below from the rules of docs/game.md: each move costs
``step_reward=-1`` except the move into a full chest (``+100`` instead), so an agent that takes a chest
``d`` moves from its start earns ``100 - (d - 1)``; the horizon is ``n * n`` joint steps.
"""

from __future__ import annotations

import json

import pytest
from conftest import assert_one_error_line

from dqn_transfer.agents import make_learner
from dqn_transfer.cli.bounds import main
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm, Bound
from dqn_transfer.envs.game import TreasureHuntGame, make_game
from dqn_transfer.envs.maps import GridMap, optimal_team_return, parse_layout
from dqn_transfer.evaluation.bounds import evaluate_bound, random_team_return
from dqn_transfer.evaluation.rollout import evaluate

# 8 moves around the wall: down 3, right 2, up 3. 100 - 7 = 93.
CORRIDOR = """
0#T.
.#..
.#..
....
"""

# Straight along row 0 is 4 moves, through the trap; the shortest trap-free path is 6 (parity rules out
# 5): 100 - 5 = 95.
TRAP_IN_THE_WAY = """
0.X.T
.....
.....
.....
.....
"""

# Chest 0 at (0, 0), chest 1 at (7, 7). Agent 0 at (2, 2): 4 to chest 0, 10 to chest 1. Agent 1 at
# (3, 3): 6 to chest 0, 8 to chest 1.
# Oracle: 0 -> chest 0 (4), 1 -> chest 1 (8): 97 + 93 = 190 in 8 steps.
# Greedy: both head for chest 0. Agent 1 goes up 3 (up comes first of the tied moves), then left, so it
# is at (0, 2) when agent 0 takes chest 0 on step 4 (97).
# - cooperative: it learns so at once; 12 more moves to chest 1: 16 moves, 85; team 182 in 16 steps.
# - competitive: it walks 2 more into the empty chest 0, then 14 to chest 1: 20 moves, 81; team 178.
# - deliberative: it follows the coordinator's assignment, which is the oracle's: 190.
SPLIT = """
T.......
........
..0.....
...1....
........
........
........
.......T
"""

# One chest, two agents: agent 0 takes it in 3 moves (98); agent 1 has no chest to go to and stays
# (moving off the grid) until the horizon, 16 steps: -16. Team 82.
ONE_CHEST_TWO_AGENTS = """
0..T
1...
....
....
"""

BOUNDS = list(Bound)
SCRIPTED = [Bound.oracle, Bound.greedy]  # they walk shortest paths
RECORD_KEYS = [
    "team_return",
    "success_rate",
    "trap_rate",
    "episode_length",
    "after_clear_rate",
    "return_after_clear",
    "agent_returns",
]


def game_of(layout: str, **rules) -> TreasureHuntGame:
    return TreasureHuntGame(parse_layout(layout), **rules)


@pytest.mark.parametrize("kind", SCRIPTED)
def test_one_agent_walks_the_corridor(kind):
    record = evaluate_bound(game_of(CORRIDOR), kind, episodes=2, seed=0)
    assert record == {
        "team_return": 93.0,
        "success_rate": 1.0,
        "trap_rate": 0.0,
        "episode_length": 8.0,
        "after_clear_rate": 0.0,
        "return_after_clear": 0.0,
        "agent_returns": [93.0],
    }


@pytest.mark.parametrize("kind", SCRIPTED)
def test_the_path_goes_round_a_trap(kind):
    record = evaluate_bound(game_of(TRAP_IN_THE_WAY), kind, episodes=1, seed=0)
    assert (record["team_return"], record["episode_length"], record["trap_rate"]) == (95.0, 6.0, 0.0)


@pytest.mark.parametrize(
    ("mode", "greedy_return", "greedy_length"),
    [("competitive", 178.0, 20.0), ("cooperative", 182.0, 16.0), ("deliberative", 190.0, 8.0)],
)
@pytest.mark.parametrize("obs_encoding", ["onehot", "coords"])
def test_the_oracle_splits_the_agents_greedy_sends_both_to_one_chest(mode, greedy_return, greedy_length, obs_encoding):
    game = game_of(SPLIT, mode=mode, obs_encoding=obs_encoding)
    oracle = evaluate_bound(game, Bound.oracle, episodes=1, seed=0)
    greedy = evaluate_bound(game, Bound.greedy, episodes=1, seed=0)
    assert (oracle["team_return"], oracle["episode_length"], oracle["agent_returns"]) == (190.0, 8.0, [97.0, 93.0])
    assert (greedy["team_return"], greedy["episode_length"]) == (greedy_return, greedy_length)
    assert greedy["agent_returns"][0] == 97.0


@pytest.mark.parametrize("reward_mode", ["individual", "team"])
def test_the_agent_without_a_chest_stays(reward_mode):
    game = game_of(ONE_CHEST_TWO_AGENTS, mode="cooperative", reward_mode=reward_mode)
    record = evaluate_bound(game, Bound.oracle, episodes=1, seed=0)
    assert (record["team_return"], record["episode_length"], record["trap_rate"]) == (82.0, 16.0, 0.0)


def unchecked_map(*rows: str) -> GridMap:
    """A map breaking only rule 3 (a chest no trap-free path reaches), built past parse_layout, which refuses it."""
    with pytest.raises(ValueError, match="closed area|unreachable"):
        parse_layout("\n".join(rows))
    cells = {
        ch: tuple((r, c) for r, row in enumerate(rows) for c, mark in enumerate(row) if mark == ch) for ch in "T#X0"
    }
    return GridMap(len(rows), rows, cells["T"], cells["X"], cells["0"], frozenset(cells["#"]))


@pytest.mark.parametrize("kind", SCRIPTED)
def test_an_unreachable_chest_leaves_the_agent_where_it_is(kind):
    # The chest is walled off: the agent at the corner stays (up is off the grid) for all 16 steps.
    walled = unchecked_map("0.#T", "..##", "....", "....")
    record = evaluate_bound(TreasureHuntGame(walled), kind, episodes=1, seed=0)
    assert (record["team_return"], record["episode_length"], record["success_rate"]) == (-16.0, 16.0, 0.0)
    # Only a path through a trap reaches the chest: the agent never crosses one. From (1, 1) it steps up
    # (the first harmless move) and then stays against the top edge: 25 steps of -1, not -100.
    behind_traps = unchecked_map(".....", ".0...", "XXXXX", ".....", "..T..")
    record = evaluate_bound(TreasureHuntGame(behind_traps), kind, episodes=1, seed=0)
    assert (record["team_return"], record["episode_length"], record["trap_rate"]) == (-25.0, 25.0, 0.0)


STUDY_M4 = dict(size=8, num_treasures=4, num_traps=4, num_agents=4, complexity=0.1)


@pytest.mark.parametrize("map_seed", [0, 1, 4])
def test_on_generated_maps_the_oracle_reaches_the_optimum_and_beats_greedy(map_seed):
    game = make_game(**STUDY_M4, map_seed=map_seed, mode="cooperative")
    oracle = evaluate_bound(game, Bound.oracle, episodes=3, seed=0)
    greedy = evaluate_bound(game, Bound.greedy, episodes=3, seed=0)
    assert oracle["team_return"] == optimal_team_return(game.map, 4)
    assert oracle["team_return"] >= greedy["team_return"]
    assert oracle["trap_rate"] == greedy["trap_rate"] == 0.0


def test_a_bound_s_record_has_a_learner_s_keys():
    game = make_game(**STUDY_M4, map_seed=0, mode="deliberative")
    learner = make_learner(AgentConfig(algorithm=Algorithm.sarsa), 4, game.obs_layout(), game.num_actions, seed=0)
    learned = evaluate(learner, game, episodes=1, seed=0, step=0)
    assert list(learned) == RECORD_KEYS
    for kind in BOUNDS:
        assert list(evaluate_bound(game, kind, episodes=1, seed=0)) == RECORD_KEYS


def test_the_command_prints_every_record(capsys):
    assert main(["--layout", SPLIT, "--mode", "cooperative", "--episodes", "2"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(line["bound"], line["team_return"]) for line in lines[:2]] == [("oracle", 190.0), ("greedy", 182.0)]
    assert lines[2]["bound"] == "random" and lines[2]["team_return"] < 182.0
    assert all(list(line)[1:] == RECORD_KEYS for line in lines)


# The agent at (0, 0) beside the chest at (0, 1), over a wall: right takes the chest, up and left leave it
# where it is, down bounces it back to its start, each -1. The horizon is 2 * 2 = 4 joint steps. A random
# agent takes the chest at step t (t = 1..4) with probability (3/4)^(t-1) / 4, for 100 - (t - 1); else -4.
BESIDE_THE_CHEST = "0T\n##"
RANDOM_EXPECTED = sum(0.75 ** (t - 1) * 0.25 * (101 - t) for t in range(1, 5)) - 4 * 0.75**4  # 66.30859375


def test_the_random_team_scores_what_a_uniform_walk_is_worth():
    game = TreasureHuntGame(parse_layout(BESIDE_THE_CHEST))
    record = evaluate_bound(game, Bound.random, episodes=4000, seed=0)
    # A return's standard deviation here is about 48, so the mean of 4000 is within 2.2 of it 99.6% of the time.
    assert record["team_return"] == pytest.approx(RANDOM_EXPECTED, abs=2.2)
    assert evaluate_bound(game, Bound.random, episodes=50, seed=0) == evaluate_bound(
        game, Bound.random, episodes=50, seed=0
    )
    assert evaluate_bound(game, Bound.random, episodes=50, seed=1) != evaluate_bound(
        game, Bound.random, episodes=50, seed=0
    )


# Two agents either side of a chest: both enter it on the first step with probability 1/16, so 200
# episodes hold a tie, drawn from the episode's generator, all but about once in 400,000; the loser's
# walk to the second chest depends on which agent it is.
CHEST_BETWEEN = "0T1\n...\n.T."


@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
@pytest.mark.parametrize("reward_mode", ["individual", "team"])
def test_the_compiled_random_team_scores_what_the_random_policy_scores(mode, reward_mode):
    tied = TreasureHuntGame(parse_layout(CHEST_BETWEEN), mode=mode, reward_mode=reward_mode)
    generated = make_game(size=6, num_agents=5, num_treasures=3, num_traps=3, map_seed=4, mode=mode, max_steps=9)
    for game, seed in [(tied, 0), (tied, 3), (generated, 1)]:
        played = evaluate_bound(game, Bound.random, episodes=200, seed=seed)["team_return"]
        assert random_team_return(game, episodes=200, seed=seed) == played


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--size", "x"], "error: argument --size: invalid int value: 'x'"),
        (["--mode", "friendly"], "error: argument --mode: invalid choice"),
        (["--size", "1"], "error: size must be >= 2, got 1"),
        (["--episodes", "0"], "error: --episodes must be at least 1, got 0"),
    ],
)
def test_bad_input_is_one_error_line(argv, message, capsys):
    assert_one_error_line(main, argv, message, capsys)
