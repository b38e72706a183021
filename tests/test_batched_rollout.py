"""All replicas' greedy evaluations as one batch give every record that evaluating them one by one gives:
the same episodes (seeds, chest ties, ties between equal values) and the same float sums."""

from __future__ import annotations

import numpy as np
import pytest

from dqn_transfer.agents import Transition, make_replicas
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm, Engine
from dqn_transfer.envs import PettingZooGame
from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.game_batch import LoopedGames
from dqn_transfer.envs.maps import generate_layout, parse_layout
from dqn_transfer.envs.observation_code import observation_code
from dqn_transfer.evaluation import batched_rollout
from dqn_transfer.evaluation.batched_rollout import GAMES_PER_BATCH, evaluate_replicas
from dqn_transfer.evaluation.rollout import EvaluationStopped, evaluate, evaluation_rng, greedy_policy
from dqn_transfer.evaluation.watch import RecordedEpisode, record_episode

SEEDS = [4, 7, 9]


def trained(algorithm: Algorithm, games: list[TreasureHuntGame], steps: int):
    """A batched learner after ``steps`` epsilon-greedy joint steps on ``games`` (one replica each): tables
    that know some states and tie on the rest; networks that moved off their initial weights."""
    hp = AgentConfig(algorithm=algorithm, engine=Engine.numpy, hidden=[16], learning_starts=20, batch_size=8)
    layout, actions = games[0].obs_layout(), games[0].num_actions
    # Tables numbered by the game's observation code: the evaluation's compiled choice (evaluation/greedy_steps.py).
    learner = make_replicas(hp, games[0].num_agents, layout, actions, seeds=SEEDS, code=observation_code(games))
    rngs = [np.random.default_rng(s) for s in SEEDS]
    for game, rng in zip(games, rngs):
        game.reset(rng)
    batch = LoopedGames(games, rngs)
    rows = len(games) * games[0].num_agents
    for step in range(1, steps + 1):
        obs, live = batch.obs.reshape(rows, -1), batch.live.reshape(rows)
        actions = learner.act(obs, live, epsilon=np.full(rows, 0.5))
        out = batch.step(actions.reshape(len(games), -1))
        flat = [a.reshape(rows, *a.shape[2:]) for a in (out.rewards, out.next_obs, out.terminated, out.truncated)]
        learner.update(Transition(obs, actions, flat[0], flat[1], flat[2], flat[3], live), step)
        batch.reset(out.episode_end)
    return learner


@pytest.mark.parametrize(
    "algorithm, rules, chests",
    [
        (Algorithm.sarsa, dict(mode="competitive"), 3),
        (Algorithm.qlearning, dict(mode="cooperative", reward_mode="team"), 3),
        (Algorithm.sarsa, dict(mode="deliberative", max_steps=15), 3),
        (Algorithm.sarsa, dict(mode="cooperative", step_reward=-0.3), 2),  # an agent plays on after the last chest
        (Algorithm.dqn, dict(mode="cooperative"), 3),
    ],
)
@pytest.mark.parametrize("games_per_batch", [GAMES_PER_BATCH, 7, 2])  # 1 batch; 3 of 2 episodes; 6 of 1
def test_one_batch_of_all_replicas_evaluations_equals_evaluating_them_one_by_one(
    algorithm, rules, chests, games_per_batch, monkeypatch
):
    monkeypatch.setattr(batched_rollout, "GAMES_PER_BATCH", games_per_batch)
    layouts = [generate_layout(6, chests, 2, 3, 0.1, seed) for seed in (1, 2, 3)]
    games = [TreasureHuntGame(parse_layout(layout), **rules) for layout in layouts]
    learner = trained(algorithm, games, steps=400)
    teams = [learner.replica(r) for r in range(3)]
    eval_games = [game.replica() for game in games]
    steps = [0, 300, 500]  # each replica's evaluation step
    pictured = [False, True, False]  # replica 1's episode 0 recorded frame by frame (an evaluation picture)
    evaluations = evaluate_replicas(learner, teams, eval_games, 6, SEEDS, steps, pictured)
    batched = [evaluation.record for evaluation in evaluations]
    one_by_one = [
        evaluate(team, game, 6, seed, step) for team, game, seed, step in zip(teams, eval_games, SEEDS, steps)
    ]
    assert batched == one_by_one  # every float bit for bit
    assert [evaluation.pictured is None for evaluation in evaluations] == [True, False, True]
    rng = evaluation_rng(SEEDS[1], steps[1], 0)
    episode = evaluations[1].pictured
    assert_same_episode(episode, record_episode(eval_games[1], greedy_policy(teams[1], rng), rng))
    if algorithm is Algorithm.dqn:
        assert episode.q_values is None  # a network's values are asked for when the picture is drawn
    else:  # a table's were kept as the episode was played
        np.testing.assert_array_equal(episode.q_values, [teams[1].q_values(obs) for obs, _ in episode.observations])
    assert len({record["team_return"] for record in batched}) > 1  # not vacuous: the replicas differ
    if chests == 2:
        assert any(record["return_after_clear"] != 0 for record in batched)


def assert_same_episode(got: RecordedEpisode, expected: RecordedEpisode) -> None:
    """The same frames, observations and result, array for array."""
    assert got.result == expected.result and len(got.frames) == len(expected.frames) == got.result.length + 1
    for mine, theirs in zip(got.frames, expected.frames):
        assert mine.step == theirs.step and mine.team_return == theirs.team_return
        for field in ("positions", "live", "chest_full"):
            np.testing.assert_array_equal(getattr(mine, field), getattr(theirs, field))
    assert len(got.observations) == len(expected.observations)
    for (obs, live), (expected_obs, expected_live) in zip(got.observations, expected.observations):
        np.testing.assert_array_equal(obs, expected_obs)
        np.testing.assert_array_equal(live, expected_live)


@pytest.mark.parametrize("algorithm", [Algorithm.qlearning, Algorithm.dqn])  # ties on unmet states; none
@pytest.mark.parametrize("games_per_batch", [GAMES_PER_BATCH, 4])  # 1 batch; 3 batches of 1 or 2 episodes
def test_another_game_s_replicas_evaluated_side_by_side_equal_evaluating_them_one_by_one(
    algorithm, games_per_batch, monkeypatch
):
    """Another PettingZoo game (the tests' corridor: agents leave early, a move may slip, drawn from each
    episode's seed): all replicas' episodes through the one episode loop give every record bit for bit."""
    monkeypatch.setattr(batched_rollout, "GAMES_PER_BATCH", games_per_batch)
    games = [PettingZooGame("corridor_env:parallel_env", {"length": 5, "slip": 0.3}) for _ in SEEDS]
    records_side_by_side_and_alone(algorithm, games, steps=300)


def records_side_by_side_and_alone(algorithm: Algorithm, games: list, steps: int) -> list[dict]:
    """A learner trained ``steps`` on ``games`` (a replica each) evaluated at three steps: the records of all
    replicas' evaluations side by side, checked equal to each one's alone and to differ between replicas."""
    learner = trained(algorithm, games, steps=steps)
    teams = [learner.replica(r) for r in range(3)]
    at = [0, steps, 2 * steps]
    evaluations = evaluate_replicas(learner, teams, [game.replica() for game in games], 5, SEEDS, at, [False] * 3)
    one_by_one = [evaluate(team, game, 5, seed, step) for team, game, seed, step in zip(teams, games, SEEDS, at)]
    assert [evaluation.record for evaluation in evaluations] == one_by_one
    assert len({record["team_return"] for record in one_by_one}) > 1  # not vacuous: the replicas differ
    return one_by_one


@pytest.mark.parametrize("fixed", [True, False], ids=["fixed_instances", "drawn_starts"])
@pytest.mark.parametrize("games_per_batch", [GAMES_PER_BATCH, 4])  # 1 batch; 3 batches of 1 or 2 episodes
def test_lbf_replicas_evaluated_as_one_batch_equal_evaluating_them_one_by_one(fixed, games_per_batch, monkeypatch):
    """LBF's evaluation games stepped as one ForagingBatch (the episodes that end early played on uncounted)
    give every record of each replica's episodes played alone, bit for bit."""
    monkeypatch.setattr(batched_rollout, "GAMES_PER_BATCH", games_per_batch)
    kwargs = dict(size=6, players=2, food=2, max_player_level=2, max_steps=20)
    games = [PettingZooGame("dqn_transfer.envs.lbf:parallel_env", kwargs, 50 + r if fixed else None) for r in range(3)]
    one_by_one = records_side_by_side_and_alone(Algorithm.qlearning, games, steps=400)
    if fixed:  # and some episodes end before others (these greedy teams finish no drawn start)
        assert len({record["episode_length"] for record in one_by_one}) > 1


def test_without_the_batched_learner_each_replica_is_evaluated_through_its_team():
    games = [TreasureHuntGame(parse_layout(generate_layout(6, 2, 2, 2, 0.1, seed))) for seed in (1, 2, 3)]
    learner = trained(Algorithm.qlearning, games, steps=200)
    teams = [learner.replica(r) for r in range(3)]
    got = evaluate_replicas(None, teams, games, 3, SEEDS, [100, 100, 100], [False, False, True])
    assert [evaluation.record for evaluation in got] == [
        evaluate(team, game, 3, seed, 100) for team, game, seed in zip(teams, games, SEEDS)
    ]
    rng = evaluation_rng(SEEDS[2], 100, 0)
    assert_same_episode(got[2].pictured, record_episode(games[2], greedy_policy(teams[2], rng), rng))


@pytest.mark.parametrize("batched", [True, False])
def test_a_stop_asked_for_ends_an_evaluation_unfinished(batched):
    """Asked after the first look (the batch looks between calls of its kernels, of at most
    STEPS_PER_CALL joint steps; replica by replica, between episodes), the evaluation raises instead of
    playing on to its end; without a stop, it ends with its records."""
    games = [TreasureHuntGame(parse_layout(generate_layout(6, 2, 2, 2, 0.1, seed))) for seed in (1, 2, 3)]
    learner = trained(Algorithm.qlearning, games, steps=200)
    teams = [learner.replica(r) for r in range(3)]
    calls = []

    def stopped() -> bool:
        calls.append(None)
        return len(calls) > 1

    with pytest.raises(EvaluationStopped):
        evaluate_replicas(learner if batched else None, teams, games, 1000, SEEDS, [0] * 3, [False] * 3, stopped)
    assert len(calls) == 2
    assert len(evaluate_replicas(learner if batched else None, teams, games, 2, SEEDS, [0] * 3, [False] * 3)) == 3
