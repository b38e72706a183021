"""Exact optimal team returns (evaluation/value_iteration.py) on hand-worked one-chest maps.

The expected values are worked out by hand from docs/game.md: every move costs ``-1`` except the move into
the full chest (``+100`` instead, and the taker ends) or into a trap (``-100`` instead, and the agent ends);
an agent still live at the horizon ``T`` has paid ``-1`` for each of the ``T`` steps. With one chest, the
best team has the nearer agent take it ``d`` moves from its start (``100 - (d - 1)``) while the other either
pays ``-T`` or, when it is cheaper, walks into a trap ``e`` moves away (``-(e - 1) - 100``).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from conftest import assert_one_error_line

from dqn_transfer.cli.claim1_exact import main
from dqn_transfer.enums import Mode
from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.maps import parse_layout
from dqn_transfer.evaluation.rollout import play_episode
from dqn_transfer.evaluation.value_iteration import (
    CLAIM1_MAP,
    CLAIM1_SEEDS,
    DRAWS,
    joint_model,
    map_values,
    optimal_values,
    stationary_team,
    table_policy,
    tie_rng,
)

CONF = Path(__file__).resolve().parents[1] / "conf"

# Agent 0 is one move from the chest: 100. Agent 1 has no trap to end in: -4 over the horizon 2 * 2 = 4.
BESIDE = "0T\n1."
# Both agents are 2 moves from the chest (99 for the taker: a tie is possible) and 2 moves from the trap.
# Horizon 9: the other pays -9, so 90. Horizon 120: the trap (-1 - 100 = -101) beats -120, so 99 - 101 = -2.
SQUARE = "0.T\n...\nX.1"


@pytest.mark.parametrize(
    ("layout", "max_steps", "optimum"), [(BESIDE, None, 96.0), (SQUARE, None, 90.0), (SQUARE, 120, -2.0)]
)
def test_hand_worked_optima_in_every_mode(layout, max_steps, optimum):
    result = map_values("hand", parse_layout(layout), max_steps)
    assert result.same_dynamics
    assert [value.joint_optimum for value in result.modes] == [optimum] * len(Mode)
    # The own-observation team of every mode, replayed through the game, reaches the joint optimum.
    assert [value.decentralised for value in result.modes] == [optimum] * len(Mode)


def test_the_team_acts_on_its_own_observations_and_avoids_the_tie():
    game = TreasureHuntGame(parse_layout(SQUARE), mode=Mode.competitive)
    model = joint_model(game)
    # The model holds the tie (both agents into the chest at step 2): two successors, one per winner.
    assert (model.successor[..., 0] != model.successor[..., 1]).any()
    tables = stationary_team(game, model, optimal_values(model, game.max_steps))
    assert tables is not None
    # Each agent's table is keyed by its own observation rows: a cell and its belief in the chest.
    assert all(len(key) == 4 * game.obs_dim for table in tables for key in table)
    episodes = [play_episode(game, table_policy(tables), tie_rng(draw)) for draw in range(DRAWS)]
    # No tie was played: both winners' generators give the same episode, agent by agent.
    assert episodes[0] == episodes[1]
    assert episodes[0].agent_returns in {(99.0, -9.0), (-9.0, 99.0)}


def test_the_horizon_lets_the_second_agent_end_in_the_trap():
    game = TreasureHuntGame(parse_layout(SQUARE), mode=Mode.cooperative, max_steps=120)
    model = joint_model(game)
    tables = stationary_team(game, model, optimal_values(model, game.max_steps))
    assert tables is not None
    episode = play_episode(game, table_policy(tables), tie_rng(0))
    assert sorted(episode.agent_returns) == [-101.0, 99.0] and episode.trap_rate == 0.5 and episode.length == 2


def test_only_one_chest_and_two_agents():
    with pytest.raises(ValueError, match="one chest and at most 2 agents"):
        joint_model(TreasureHuntGame(parse_layout("0T.\n...\n1.T")))


def test_the_claim1_maps_are_the_experiment_s():
    simple = yaml.safe_load((CONF / "env" / "simple.yaml").read_text())
    claim1 = yaml.safe_load((CONF / "experiment" / "claim1.yaml").read_text())
    expected = {key: {**simple, **claim1["env"]}[key] for key in CLAIM1_MAP}
    assert expected == CLAIM1_MAP
    assert list(CLAIM1_SEEDS) == list(range(claim1["replicas"]["maps"]))


def test_the_command_prints_a_table(capsys):
    assert main(["--maps", "4x4"]) == 0
    rows = capsys.readouterr().out.splitlines()
    # 4x4: agent 1 takes the chest in 2 moves (99), agent 0 pays the horizon of 16: 83, in every mode.
    assert rows[2] == "| 4x4 | 4 | 16 | " + rows[2].split(" | ")[3] + " | yes | 83 | 83 | 83 | 83 | 0 |"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--maps", "4x4", "7x7"], "error: unknown map '7x7'"),
        (["--maps", "claim1:x"], "error: unknown map 'claim1:x'"),
        (["--max-steps", "0", "--maps", "4x4"], "error: max_steps must be an integer >= 1, got 0"),
        (["--max-steps", "x"], "error: argument --max-steps: invalid int value: 'x'"),
    ],
)
def test_bad_input_is_one_error_line(argv, message, capsys):
    assert_one_error_line(main, argv, message, capsys)


def test_tie_generators_draw_each_winner():
    assert [tie_rng(draw).integers(DRAWS) for draw in range(DRAWS)] == [0, 1]
