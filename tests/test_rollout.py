"""What happens after the last full chest is taken: ``EpisodeResult.steps_after_clear`` and
``return_after_clear`` of :func:`dqn_transfer.evaluation.rollout.play_episode`, and the ``after_clear_rate`` and
``return_after_clear`` keys of :func:`~dqn_transfer.evaluation.rollout.evaluate`, and each agent's return
(``EpisodeResult.agent_returns``, ``evaluate``'s ``agent_returns``); values worked out by hand from the rules
of docs/game.md.

Actions: 0 up, 1 down, 2 left, 3 right.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import agent_meta, read_metrics

from dqn_transfer.config import AgentConfig, TrainConfig
from dqn_transfer.enums import Algorithm, Logger
from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.maps import parse_layout
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.evaluation.rollout import EpisodeResult, evaluate, play_episode
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3

# One chest at (0,2). Agent 0 at (0,0) takes it with RIGHT, RIGHT (k = 2 joint steps); agent 1 at
# (2,0) moving DOWN bumps the bottom edge and stays there, never ending before the horizon.
ONE_CHEST = """
0.T
...
1..
"""


def scripted(*columns: list[int]):
    """A policy playing ``columns[agent][t]`` at joint step t (the last entry once the list runs out)."""
    t = [0]

    def policy(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        step = t[0]
        t[0] += 1
        return np.array([column[min(step, len(column) - 1)] for column in columns])

    return policy


def game_of(layout: str, **kwargs) -> TreasureHuntGame:
    return TreasureHuntGame(parse_layout(layout), mode=kwargs.pop("mode", "cooperative"), **kwargs)


@pytest.mark.parametrize("reward_mode", ["individual", "team"])
@pytest.mark.parametrize(("max_steps", "horizon"), [(None, 9), (5, 5)])  # None: n * n = 9
def test_an_agent_playing_on_after_the_last_chest(reward_mode, max_steps, horizon):
    game = game_of(ONE_CHEST, reward_mode=reward_mode, max_steps=max_steps)
    result = play_episode(game, scripted([RIGHT], [DOWN]), np.random.default_rng(0))
    k = 2  # agent 0 enters the chest on joint step 2
    assert result.length == horizon and result.treasures_collected == 1
    # agent 0: -1 + 100; agent 1: -1 on each of the horizon's steps (in team mode each step's sum
    # is counted once, so the team return is the same)
    assert result.team_return == 99.0 - horizon
    assert result.steps_after_clear == horizon - k
    assert result.return_after_clear == -(horizon - k)
    if reward_mode == "individual":
        assert result.agent_returns == (99.0, -horizon)
    else:  # each live agent receives the step's sum: -2, then 99 (100 - 1); agent 1 alone then, -1 a step
        assert result.agent_returns == (-2.0 + 99.0, -2.0 + 99.0 - (horizon - k))


def test_the_last_of_several_chests_counts():
    # chests at (0,2) and (2,2); agent 0 takes (0,2) on step 2; agent 1 at (3,0) goes RIGHT (3,1),
    # RIGHT (3,2), UP (2,2) and takes the last chest on step 3; agent 2 at (3,3) bumps the bottom
    # edge until the horizon 4 * 4 = 16
    game = game_of("0.T.\n....\n..T.\n1..2")
    result = play_episode(game, scripted([RIGHT], [RIGHT, RIGHT, UP], [DOWN]), np.random.default_rng(0))
    assert result.length == 16 and result.treasures_collected == 2
    assert result.steps_after_clear == 16 - 3
    assert result.return_after_clear == -(16 - 3)
    assert result.team_return == 99.0 + 98.0 - 16


def test_an_episode_that_ends_with_the_last_chest():
    # agent 0 takes the chest on step 2 while agent 1 walks RIGHT, RIGHT into the trap at (2,2) on
    # step 2 too: the episode ends with the chest (team return 99 + (-1 - 100))
    game = game_of("0.T\n...\n1.X")
    result = play_episode(game, scripted([RIGHT], [RIGHT]), np.random.default_rng(0))
    assert result.length == 2 and result.team_return == 99.0 - 1.0 - 100.0
    assert (result.steps_after_clear, result.return_after_clear) == (0, 0.0)
    # a lone agent: the last chest always ends the episode
    lone = game_of("0.T\n...\n...")
    result = play_episode(lone, scripted([RIGHT]), np.random.default_rng(0))
    assert result == EpisodeResult(99.0, 2, 1, 1.0, 0.0, 0, 0.0, (99.0,))


def test_a_chest_left_full_is_never_cleared():
    # two chests, agent 0 takes (0,2) on step 2, agent 1 bumps the bottom edge until the horizon 9
    # without taking (2,2): chests remain, so nothing is "after the clear"
    game = game_of("0.T\n...\n1.T")
    result = play_episode(game, scripted([RIGHT], [DOWN]), np.random.default_rng(0))
    assert result.length == 9 and result.treasures_collected == 1
    assert (result.steps_after_clear, result.return_after_clear) == (0, 0.0)


def test_the_first_five_fields_count_return_steps_chests_and_traps():
    # agent 1 at (3,0) steps RIGHT into the trap at (3,1) on step 1 (-100) and leaves the game; agent 0
    # takes the chest at (0,3) on step 3 (-1, -1, +100) and leaves it too: with nobody left playing the
    # episode ends there, with one of the two chests full and one of the two agents trapped
    game = game_of("0..T\n....\n....\n1X.T")
    result = play_episode(game, scripted([RIGHT], [RIGHT]), np.random.default_rng(0))
    assert result == EpisodeResult(
        team_return=98.0 - 100.0,
        length=3,
        treasures_collected=1,
        success_rate=0.5,
        trap_rate=0.5,
        steps_after_clear=0,  # the map was never cleared
        return_after_clear=0.0,
        agent_returns=(98.0, -100.0),  # the trap's reward replaces the step's
    )


class StubLearner:
    """Greedy actions without a network: agent 0 always RIGHT, agent 1 always DOWN (ONE_CHEST's script)."""

    def greedy(self, obs, live, ties=None):
        return np.array([RIGHT, DOWN])


def test_evaluate_appends_the_after_clear_keys():
    game = game_of(ONE_CHEST)
    result = evaluate(StubLearner(), game, episodes=3, seed=0, step=0)
    assert list(result) == [
        "team_return",
        "success_rate",
        "trap_rate",
        "episode_length",
        "after_clear_rate",
        "return_after_clear",
        "agent_returns",
    ]
    assert result == {
        "team_return": 90.0,
        "success_rate": 1.0,
        "trap_rate": 0.0,
        "episode_length": 9.0,
        "after_clear_rate": 1.0,
        "return_after_clear": -7.0,
        "agent_returns": [99.0, -9.0],  # agent 0: -1 + 100; agent 1: -1 on each of the 9 steps
    }
    # with a first episode that ended with the chest: means over 1 + 3 = 4 episodes, 0 for it
    first = EpisodeResult(99.0, 2, 1, 1.0, 0.0, 0, 0.0, (100.0, -1.0))
    result = evaluate(StubLearner(), game, episodes=4, seed=0, step=0, first=first)
    assert result["after_clear_rate"] == 0.75
    assert result["return_after_clear"] == -7.0 * 3 / 4
    assert result["team_return"] == (99.0 + 3 * 90.0) / 4
    assert result["agent_returns"] == [(100.0 + 3 * 99.0) / 4, (-1.0 + 3 * -9.0) / 4]


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_every_evaluation_record_has_each_agent_s_return(tmp_path):
    """A run's ``metrics.jsonl``: each line one return per agent, which with individual rewards sum to the
    team return (it adds the live agents' rewards; a done agent receives 0); the checkpoints' ``last_eval``
    keeps the team's means only, as before."""
    config = TrainConfig(
        env=EnvConfig(layout="0...T\n.#...\n...#.\nX....\n1..T.\n"),
        agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.1),
        seed=3,
        total_steps=400,
        eval_every=100,
        eval_episodes=3,
        checkpoint_every=400,
        progress=False,
        logger=[Logger.csv],
    )
    train(plan_run(config), tmp_path / "run")
    records = read_metrics(tmp_path / "run")
    assert [r["step"] for r in records] == [0, 100, 200, 300, 400]
    for record in records:
        assert len(record["agent_returns"]) == 2
        assert sum(record["agent_returns"]) == pytest.approx(record["team_return"], abs=1e-9)
    assert len({tuple(r["agent_returns"]) for r in records}) > 1  # not one value throughout
    meta = agent_meta(tmp_path / "run" / "checkpoints" / "agent_0.safetensors")
    assert meta["last_eval"] == {k: v for k, v in records[-1].items() if k in meta["last_eval"]}
    assert "agent_returns" not in meta["last_eval"] and "team_return" in meta["last_eval"]
