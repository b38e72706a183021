"""The learners' capabilities (dqn_transfer.agents.base), tested through the same methods for both
families: knowledge exchange, greedy acting, replica views, and the plan's refusal of a configuration
whose learner lacks a capability it asks for."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dqn_transfer.agents import (
    Experience,
    ExperienceSharing,
    KnowledgeExchange,
    Learner,
    Team,
    Transition,
    VisitExchange,
    WarmStart,
    make_learner,
    make_replicas,
)
from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.config import AgentConfig, ConfigError, TrainConfig, TransferConfig, validate
from dqn_transfer.enums import Algorithm, Engine, Exchange
from dqn_transfer.exchange import check_exchange
from dqn_transfer.exchange.best import exchange_best
from dqn_transfer.exchange.shared_replay import exchange_replay

LAYOUT = [("position", 4)]
A = 3
STATES = np.eye(4, dtype=np.float32)
TABULAR = AgentConfig(algorithm=Algorithm.qlearning, lr=0.5, gamma=0.9)
DQN = AgentConfig(algorithm=Algorithm.dqn, engine=Engine.numpy, hidden=[8], learning_starts=1, batch_size=4)
FAMILIES = pytest.mark.parametrize("hp", [TABULAR, DQN], ids=["tabular", "dqn"])


def trained(hp: AgentConfig, num_agents: int = 3, seeds: list[int] | None = None, steps: int = 40) -> Learner:
    """A learner whose agents learned apart (other rewards per agent), so their values differ."""
    learner = make_replicas(hp, num_agents, LAYOUT, A, seeds=seeds or [0])
    rows = learner.num_rows
    rng = np.random.default_rng(3)
    for step in range(1, steps + 1):
        obs = STATES[rng.integers(4, size=rows)]
        actions = learner.act(obs, np.ones(rows, bool), 0.5)
        rewards = (np.arange(rows) % num_agents + 1).astype(np.float32) * (actions == 1)
        done = np.zeros(rows, bool)
        learner.update(Transition(obs, actions, rewards, obs[::-1].copy(), done, done, np.ones(rows, bool)), step)
    return learner


def all_states(team: Team, i: int) -> np.ndarray:
    """Agent i's Q-values of the four states, ``[4, A]``."""
    return np.stack([team.q_values(np.repeat(state[None], team.num_agents, axis=0))[i] for state in STATES])


@FAMILIES
def test_exchange_best_with_tau_1_makes_every_agent_the_best_one(hp):
    team = trained(hp)
    before = [all_states(team, i) for i in range(3)]
    assert not np.allclose(before[0], before[1])
    best = exchange_best(team, np.array([[0.0, 5.0, 1.0], [0.0, 3.0, 1.0]]), tau=1.0)
    assert best == 1
    for i in range(3):
        np.testing.assert_allclose(all_states(team, i), before[1], rtol=1e-6, atol=1e-6)


@FAMILIES
def test_exchange_best_moves_the_others_part_of_the_way_and_leaves_the_best_alone(hp):
    team = trained(hp)
    before = [all_states(team, i) for i in range(3)]
    exchange_best(team, np.array([[9.0, 0.0, 1.0]]), tau=0.5)
    np.testing.assert_array_equal(all_states(team, 0), before[0])
    for i in (1, 2):
        after = all_states(team, i)
        assert not np.array_equal(after, before[i])
        assert np.abs(after - before[0]).sum() < np.abs(before[i] - before[0]).sum()


@FAMILIES
def test_a_replica_exchanges_within_its_own_team(hp):
    learner = trained(hp, num_agents=2, seeds=[4, 5])
    other = [all_states(learner.replica(0), i) for i in range(2)]
    exchange_best(learner.replica(1), np.array([[0.0, 1.0]]), tau=1.0)
    np.testing.assert_array_equal(all_states(learner.replica(1), 0), all_states(learner.replica(1), 1))
    for i in range(2):  # replica 0 untouched
        np.testing.assert_array_equal(all_states(learner.replica(0), i), other[i])


@FAMILIES
def test_shared_replay_gives_only_the_team_mates_their_transitions(hp):
    team = make_learner(dataclasses.replace(hp, learning_starts=10**6) if hp is DQN else hp, 2, LAYOUT, A, seed=0)
    before = [all_states(team, i) for i in range(2)]
    steps = [
        Transition(
            STATES[[0, 1]],
            np.array([1, 2]),
            np.array([1.0, 1.0], np.float32),
            STATES[[2, 3]],
            np.array([True, True]),
            np.zeros(2, bool),
            np.array([True, False]),  # only agent 0 acted
        )
    ]
    exchange_replay(team, steps, [np.zeros(2, bool)])
    if hp is DQN:  # into agent 1's replay, not agent 0's
        assert team.replay.size.tolist() == [0, 1]
    else:  # a table learns at once: agent 1's Q(s0, 1) = 0.5 * 1
        assert all_states(team, 1)[0, 1] == pytest.approx(0.5)
    np.testing.assert_array_equal(all_states(team, 0), before[0])


def test_learn_from_updates_a_table_like_its_own_step_without_caching_a_next_action():
    sarsa = dataclasses.replace(TABULAR, algorithm=Algorithm.sarsa)
    a, b = (make_learner(sarsa, 1, LAYOUT, A, seed=0) for _ in range(2))
    experience = Experience(STATES[[0]], np.array([2]), np.array([1.0], np.float32), STATES[[1]], np.array([False]))
    a.learn_from(0, experience)
    b.update(Transition(*experience, np.array([True]), np.array([True])), 1)  # truncated: no cache either
    np.testing.assert_array_equal(all_states(a, 0), all_states(b, 0))
    assert a.next_action.tolist() == b.next_action.tolist() == [-1]


@FAMILIES
def test_greedy_gives_non_live_agents_action_0_and_ties_to_the_drawn_best_action(hp):
    team = make_learner(hp, 2, LAYOUT, A, seed=0)
    obs = STATES[[0, 1]]
    best = team.best_actions(obs)
    assert best.shape == (2, A) and best.any(axis=1).all()
    greedy = team.greedy(obs, np.array([True, False]), np.random.default_rng(1))
    assert greedy[1] == 0 and best[0, greedy[0]]
    assert team.act(obs, np.array([False, True]), 0.5)[0] == 0


def test_replica_views_have_exactly_their_learners_capabilities():
    tabular = make_replicas(TABULAR, 2, LAYOUT, A, seeds=[1, 2]).replica(1)
    dqn = make_replicas(DQN, 2, LAYOUT, A, seeds=[1, 2]).replica(1)
    assert isinstance(tabular, KnowledgeExchange) and not isinstance(tabular, WarmStart)
    assert isinstance(dqn, KnowledgeExchange) and isinstance(dqn, WarmStart)


# The capability each exchange's hooks call on the learner (exchange/*.py), stated here apart from the code.
HOOKS_CALL = {
    Exchange.best: KnowledgeExchange,
    Exchange.shared_replay: KnowledgeExchange,
    Exchange.experience: ExperienceSharing,
    Exchange.confidence: VisitExchange,
    Exchange.advice: VisitExchange,
}
LEARNER_OF = {Algorithm.sarsa: TabularLearner, Algorithm.qlearning: TabularLearner, Algorithm.dqn: BatchedDQN}


@pytest.mark.parametrize("exchange", list(HOOKS_CALL))
@pytest.mark.parametrize("algorithm", list(LEARNER_OF))
def test_the_plan_lets_an_exchange_run_exactly_when_its_learner_has_the_capability_its_hooks_call(exchange, algorithm):
    """The hooks do not check capabilities again: the plan's refusal must cover every learner that lacks one."""
    config = TrainConfig(agent=AgentConfig(algorithm=algorithm), transfer=TransferConfig(exchange=exchange))
    if issubclass(LEARNER_OF[algorithm], HOOKS_CALL[exchange]):
        check_exchange(config)
    else:
        with pytest.raises(ConfigError, match=f"^transfer.exchange={exchange.value} .*not agent={algorithm.value}$"):
            check_exchange(config)


def test_a_warm_start_a_table_cannot_take_is_refused_when_the_config_is_checked():
    for transfer, refusal in (
        (TransferConfig(enabled=True, reset_optimizer=False), "transfer.reset_optimizer=false .* tabular"),
        (TransferConfig(enabled=True, freeze=[0]), "transfer.freeze .* tabular"),
    ):
        with pytest.raises(ConfigError, match=refusal):
            validate(TrainConfig(agent=TABULAR, transfer=transfer))
    validate(TrainConfig(agent=TABULAR, transfer=TransferConfig(enabled=True)))  # nothing a table lacks
