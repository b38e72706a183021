"""The exchanges by visit counts (``transfer.exchange=confidence|advice``), worked out by hand, and
in training: advice never given changes nothing, and both resume bit for bit."""

import dataclasses

import numpy as np
import pytest
from conftest import agent_meta, checked, read_metrics, without_timing
from test_train_cli import MAP, kill_and_resume

from dqn_transfer.agents import AdviceRules, TabularLearner, Transition
from dqn_transfer.config import AgentConfig, ConfigError, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Exchange
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.exchange.confidence import Confidence
from dqn_transfer.exchange.shared_replay import exchange_replay
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

S0, S1, S2 = np.eye(3, dtype=np.float32)


def tables(num_agents: int = 2, algorithm: Algorithm = Algorithm.qlearning, seeds=(0,)) -> TabularLearner:
    hp = AgentConfig(algorithm=algorithm, lr=0.5, gamma=0.9)
    return TabularLearner(num_agents, [("position", 3)], 2, hp, seed=list(seeds))


def state(learner: TabularLearner, obs: np.ndarray, row: int = 0) -> int:
    """The id of ``obs`` in the index of ``row``'s replica."""
    return int(learner.state_ids(obs[None], np.array([row]))[0])


def exchange_confidence(team, weight: float) -> None:
    """The ``confidence`` method's exchange in ``team`` (it reads no returns)."""
    Confidence(TransferConfig(exchange=Exchange.confidence, confidence_weight=weight), 1).exchange(0, team, np.zeros(0))


def give(learner: TabularLearner, row: int, values: dict[int, list[float]], visits: dict[int, int]) -> None:
    """Row ``row`` holds ``values`` of the states S<n> and has visited them ``visits`` times."""
    keys = np.stack([np.eye(3, dtype=np.float32)[n] for n in values])
    learner.load_agent_tensors(row, {"keys": keys, "values": np.array(list(values.values()), np.float32)})
    for n, count in visits.items():
        learner.visits[row, state(learner, np.eye(3, dtype=np.float32)[n], row)] = count


# ------------------------------------------------------------------------------------ confidence


def test_confidence_moves_toward_the_more_visiting_team_mate_by_its_share_of_the_visits():
    learner = tables()
    give(learner, 0, {0: [0.0, 4.0], 1: [2.0, 2.0]}, {0: 1, 1: 2})  # agent 0: S0 once, S1 twice
    give(learner, 1, {0: [8.0, 0.0], 2: [5.0, 5.0]}, {0: 3})  # agent 1: S0 three times; S2 loaded, never visited
    exchange_confidence(learner.replica(0), 1.0)
    # S0: w = 3 / (1 + 3) = 3/4 of the way: [0 + 3/4 * 8, 4 - 3/4 * 4] = [6, 1]; agent 1 visited it more: unchanged
    np.testing.assert_array_equal(learner.agent_q_values(0, S0), [6.0, 1.0])
    np.testing.assert_array_equal(learner.agent_q_values(1, S0), [8.0, 0.0])
    # S1, which only agent 0 visited: agent 0 keeps it; agent 1 (0 visits) copies it, w = 2 / 2 = 1
    np.testing.assert_array_equal(learner.agent_q_values(0, S1), [2.0, 2.0])
    np.testing.assert_array_equal(learner.agent_q_values(1, S1), [2.0, 2.0])
    # S2: agent 1 holds values but never visited it: agent 0 does not move toward them
    np.testing.assert_array_equal(learner.agent_q_values(0, S2), [0.0, 0.0])
    np.testing.assert_array_equal(learner.agent_tensors(0)["keys"], np.stack([S0, S1]))  # S2 not entered
    np.testing.assert_array_equal(learner.agent_tensors(1)["keys"], np.stack([S0, S2, S1]))  # S1 entered last


def test_confidence_weight_scales_the_move_and_visits_are_the_agents_own_updates():
    learner = tables()
    give(learner, 0, {0: [0.0, 4.0]}, {0: 1})
    give(learner, 1, {0: [8.0, 0.0]}, {0: 3})
    exchange_confidence(learner.replica(0), 0.5)  # w = 0.5 * 3/4 = 3/8
    np.testing.assert_array_equal(learner.agent_q_values(0, S0), [3.0, 2.5])
    assert learner.visits[:, state(learner, S0)].tolist() == [1, 3]  # a merge is no visit

    # An own update counts; learning from a team-mate's transitions does not.
    live = np.array([True, False])
    learner.update(
        Transition(np.stack([S1, S1]), np.array([0, 0]), np.ones(2), np.stack([S2, S2]), live, ~live, live), 1
    )
    assert learner.visits[:, state(learner, S1)].tolist() == [1, 0]
    assert learner.visits[:, state(learner, S2)].tolist() == [0, 0]  # s' is not visited by an update on s
    exchange_replay(
        learner.replica(0),
        [Transition(np.stack([S1, S1]), np.array([0, 0]), np.ones(2), np.stack([S2, S2]), live, ~live, live)],
        [np.zeros(2, bool)],
    )
    assert learner.agent_tensors(1)["keys"].tolist() == [S0.tolist(), S1.tolist()]  # agent 1 learned S1 ...
    assert learner.visits[:, state(learner, S1)].tolist() == [1, 0]  # ... without visiting it


def test_a_replicas_confidence_exchange_leaves_the_other_replicas_untouched():
    learner = tables(seeds=(0, 1))
    for replica in (0, 1):
        give(learner, 2 * replica, {0: [0.0, 4.0]}, {0: 1})
        give(learner, 2 * replica + 1, {0: [8.0, 0.0]}, {0: 3})
    before = learner.q.copy()
    exchange_confidence(learner.replica(1), 1.0)
    np.testing.assert_array_equal(learner.q[:2], before[:2])
    np.testing.assert_array_equal(learner.agent_q_values(2, S0), [6.0, 1.0])


# ---------------------------------------------------------------------------------------- advice


def advised_team(advisor_visits: int, budget: int = 2, algorithm: Algorithm = Algorithm.qlearning) -> TabularLearner:
    """Agent 0 prefers action 0 in S0 (visited once); agent 1 prefers action 1 there (visited ``advisor_visits``)."""
    learner = tables(algorithm=algorithm)
    give(learner, 0, {0: [3.0, 0.0]}, {0: 1})
    give(learner, 1, {0: [0.0, 5.0]}, {0: advisor_visits})
    learner.start_advice(AdviceRules(ask_below=3, answer_from=10, budget=budget))
    return learner


def test_a_student_gets_the_advisors_greedy_action_while_its_budget_lasts():
    learner = advised_team(advisor_visits=10)
    both, live = np.stack([S0, S0]), np.ones(2, dtype=bool)
    assert learner.act(both, live, epsilon=0.0).tolist() == [1, 1]  # agent 1 (10 visits) is no student
    assert learner.advice_left.tolist() == [1, 2]
    assert learner.act(both, live, epsilon=0.0).tolist() == [1, 1]
    assert learner.act(both, live, epsilon=0.0).tolist() == [0, 1]  # budget spent: its own action again
    assert learner.advice_left.tolist() == [0, 2]


def test_no_advice_from_a_team_mate_below_the_threshold_nor_in_greedy_evaluation():
    learner = advised_team(advisor_visits=9)
    both, live = np.stack([S0, S0]), np.ones(2, dtype=bool)
    assert learner.act(both, live, epsilon=0.0).tolist() == [0, 1]
    learner = advised_team(advisor_visits=10)
    assert learner.greedy(both, live).tolist() == [0, 1]  # evaluation plays the agents' own values
    assert learner.replica(0).greedy(both, live).tolist() == [0, 1]
    assert learner.advice_left.tolist() == [2, 2]


def test_advice_ties_go_to_the_lowest_team_mate_and_the_lowest_best_action():
    learner = tables(num_agents=3)
    give(learner, 0, {0: [0.0, 3.0]}, {})  # its own greedy action: 1
    give(learner, 1, {0: [2.0, 2.0]}, {0: 10})  # tied best actions: 0
    give(learner, 2, {0: [0.0, 9.0]}, {0: 10})  # as experienced as agent 1, higher index
    learner.start_advice(AdviceRules(3, 10, 5))
    assert learner.act(np.stack([S0] * 3), np.array([True, False, False]), epsilon=0.0).tolist() == [0, 0, 0]
    assert learner.advice_left.tolist() == [4, 5, 5]


def test_sarsa_bootstraps_on_the_advised_next_action_it_then_plays():
    """Agent 0 steps S0 -> S1 (reward 1); in S1 its own greedy action is 0 (Q = 2), agent 1's (10 visits)
    is 1 (agent 0's Q(S1, 1) = 0). The update picks a' = 1 by advice: y = 1 + 0.9 * 0, Q(S0, 0) = 0.5
    (without advice y = 1 + 0.9 * 2 = 2.8), and the next act plays it, spending the budget once."""
    learner = tables(algorithm=Algorithm.sarsa)
    give(learner, 0, {1: [2.0, 0.0]}, {})
    give(learner, 1, {1: [0.0, 4.0]}, {1: 10})
    learner.start_advice(AdviceRules(3, 10, 5))
    live = np.array([True, False])
    learner.act(np.stack([S0, S0]), live, epsilon=0.0)  # nobody visited S0: no advice
    assert learner.advice_left.tolist() == [5, 5]
    no = np.zeros(2, dtype=bool)
    learner.update(Transition(np.stack([S0, S0]), np.array([0, 0]), np.ones(2), np.stack([S1, S1]), no, no, live), 1)
    np.testing.assert_allclose(learner.agent_q_values(0, S0), [0.5, 0.0])
    assert learner.next_action[0] == 1 and learner.advice_left.tolist() == [4, 5]
    assert learner.act(np.stack([S1, S1]), live, epsilon=0.0).tolist() == [1, 0]
    assert learner.advice_left.tolist() == [4, 5]


# -------------------------------------------------------------------------------------- in training


def run_config(exchange: Exchange, resume: bool = False, **transfer) -> TrainConfig:
    return TrainConfig(
        env=EnvConfig(layout=MAP),
        agent=AgentConfig(algorithm=Algorithm.sarsa, lr=0.1),
        seed=0,
        total_steps=240,
        eval_every=40,
        eval_episodes=1,
        checkpoint_every=30,
        progress=False,
        resume=resume,
        transfer=TransferConfig(exchange=exchange, exchange_every=3, **transfer),
    )


def final_digests(run_dir) -> list[str]:
    return [agent_meta(run_dir / "checkpoints" / f"agent_{i}.safetensors")["digest"] for i in range(2)]


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_advice_never_given_is_the_run_without_advice_bit_for_bit(tmp_path):
    Trainer(plan_run(run_config(Exchange.none)), tmp_path / "none").run()
    silent = Trainer(plan_run(run_config(Exchange.advice, advice_answer_from=10**9)), tmp_path / "silent")
    silent.run()
    assert silent.learner.advice_left.tolist() == [500, 500]
    assert without_timing(read_metrics(tmp_path / "silent")) == without_timing(read_metrics(tmp_path / "none"))
    assert final_digests(tmp_path / "silent") == final_digests(tmp_path / "none")
    advised = Trainer(plan_run(run_config(Exchange.advice, advice_answer_from=3)), tmp_path / "advised")
    advised.run()
    assert (advised.learner.advice_left < 500).all()  # the same run with advice given does change
    assert final_digests(tmp_path / "advised") != final_digests(tmp_path / "none")


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
@pytest.mark.parametrize(
    ("exchange", "settings"),
    [
        (Exchange.confidence, {"confidence_weight": 0.5}),
        (Exchange.advice, {"advice_answer_from": 3, "advice_budget": 60}),
    ],
)
def test_a_run_killed_mid_run_resumes_bit_for_bit(tmp_path, monkeypatch, exchange, settings):
    """Killed at a checkpoint after some exchange (a merge, or advice given with budget left) and resumed:
    visit counts and budgets come back, and the run ends as the uninterrupted one."""

    def exchanged(trainer) -> bool:
        if exchange is Exchange.advice:
            return 0 < trainer.learner.advice_left.sum() < 120
        return trainer.replicas[0].counters.episodes > 3

    resumed, reference = kill_and_resume(
        tmp_path, monkeypatch, lambda resume=False: run_config(exchange, resume, **settings), dies=exchanged
    )
    assert resumed == reference
    assert final_digests(tmp_path / "killed") == final_digests(tmp_path / "reference")


# ----------------------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"exchange": Exchange.confidence}, "transfer.exchange=confidence .* needs a tabular learner"),
        ({"exchange": Exchange.advice}, "transfer.exchange=advice .* needs a tabular learner"),
        ({"confidence_weight": 0.0}, r"transfer.confidence_weight must be in \(0, 1\]"),
        ({"confidence_weight": 1.5}, r"transfer.confidence_weight must be in \(0, 1\]"),
        ({"advice_budget": -1}, "transfer.advice_budget must be >= 0"),
        ({"advice_answer_from": 0}, "transfer.advice_answer_from must be >= 1"),
        ({"advice_ask_below": -1}, "transfer.advice_ask_below must be >= 0"),
    ],
)
def test_bad_settings_are_refused_in_one_line(change, message):
    tabular = "exchange" not in change
    config = run_config(Exchange.none)
    agent = AgentConfig(algorithm=Algorithm.sarsa if tabular else Algorithm.double_dqn)
    config = dataclasses.replace(config, agent=agent, transfer=dataclasses.replace(config.transfer, **change))
    with pytest.raises(ConfigError, match=message):
        checked(config)
