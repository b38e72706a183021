"""Counter-based draws and the array tabular learner built on them: a draw is a function of its key,
uniform, and a replica's draws are its lone run's whatever else is in the batch."""

from __future__ import annotations

import numpy as np
import pytest

from dqn_transfer.agents import TabularLearner, Transition
from dqn_transfer.agents.random_streams import mix64, stream_keys, uniforms
from dqn_transfer.agents.tabular_kernels import epsilon_greedy_rows
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm


def test_splitmix64_finalizer_matches_its_reference_values():
    # SplitMix64 seeded with 0 yields mix64(k * 0x9E3779B97F4A7C15) for k = 1, 2, ...: its published
    # first outputs (e.g. the xoshiro authors' splitmix64.c with x = 0).
    golden = np.uint64(0x9E3779B97F4A7C15)
    with np.errstate(over="ignore"):
        states = np.arange(1, 4, dtype=np.uint64) * golden
    assert [hex(int(v)) for v in mix64(states)] == ["0xe220a8397b1dcdaf", "0x6e789e6aa1b965f4", "0x6c45d188009454f"]


def draws(seed: int, stream: int, counter: int, agents: list[int]) -> np.ndarray:
    keys = stream_keys(np.full(len(agents), seed), stream, np.array(agents))
    return uniforms(keys, counter, 3)


def test_a_draw_depends_on_every_part_of_its_key_and_on_nothing_else():
    base = draws(7, 1, 3, [0, 1])
    assert base.shape == (2, 3) and ((base >= 0) & (base < 1)).all()
    keys = stream_keys(np.array([7, 7]), 1, np.array([0, 1]))
    np.testing.assert_array_equal(base, uniforms(keys, np.array([3, 3]), 3))  # pure
    np.testing.assert_array_equal(draws(7, 1, 3, [1])[0], base[1])  # a row's draws ignore the other rows
    for changed in (draws(8, 1, 3, [0, 1]), draws(7, 2, 3, [0, 1]), draws(7, 1, 4, [0, 1]), draws(7, 1, 3, [2, 3])):
        assert not np.isin(changed, base).any()
    assert len(set(base.ravel().tolist())) == 6  # slots differ too


def test_draws_are_uniform_and_successive_counters_are_uncorrelated():
    n = 200_000
    u = uniforms(stream_keys(np.full(n, 11), 1, np.zeros(n, dtype=np.int64)), np.arange(n), 2)
    counts = np.bincount((u[:, 0] * 20).astype(int), minlength=20)
    chi2 = float(((counts - n / 20) ** 2 / (n / 20)).sum())
    assert chi2 < 45.3  # the 0.999 quantile of chi-square with 19 degrees of freedom
    assert abs(np.corrcoef(u[:-1, 0], u[1:, 0])[0, 1]) < 0.01
    assert abs(np.corrcoef(u[:, 0], u[:, 1])[0, 1]) < 0.01


def test_epsilon_greedy_rows_worked_by_hand():
    q = np.array([[1.0, 3.0, 3.0, 0.0]] * 4, dtype=np.float32)
    eps = np.array([0.5, 0.5, 0.5, 0.0])
    draws = np.array(
        [
            [0.9, 0.1, 0.74],  # no exploring (0.9 >= 0.5); ties 1 and 2, pick floor(0.74 * 2) = 1 -> action 2
            [0.9, 0.1, 0.20],  # pick 0 -> action 1
            [0.1, 0.99, 0.5],  # explores: floor(0.99 * 4) = 3
            [0.0, 0.99, 0.5],  # epsilon 0 never explores (0.0 < 0.0 is false): pick 1 -> action 2
        ]
    )
    np.testing.assert_array_equal(epsilon_greedy_rows(q, eps, draws), [2, 1, 3, 2])


@pytest.mark.parametrize("algorithm", [Algorithm.sarsa, Algorithm.qlearning])
def test_a_replica_acts_and_learns_as_the_lone_learner_of_its_seed(algorithm):
    hp = AgentConfig(algorithm=algorithm, lr=0.2, gamma=0.9)
    lone = TabularLearner(3, [("position", 4)], 4, hp, seed=5)
    batch = TabularLearner(3, [("position", 4)], 4, hp, seed=[2, 5, 9])
    # The same data for replica 1 as for the lone learner; other data for the other replicas.
    data = np.random.default_rng(0)
    states = np.eye(4, dtype=np.float32)
    for step in range(1, 80):
        s, s_next = data.integers(4, size=9), data.integers(4, size=9)
        live, rewards, done = data.random(9) < 0.8, data.normal(size=9), data.random(9) < 0.1
        s[3:6], s_next[3:6] = s[:3], s_next[:3]
        live[3:6], rewards[3:6], done[3:6] = live[:3], rewards[:3], done[:3]
        act = batch.act(states[s], live, epsilon=0.3)
        own = lone.act(states[s[:3]], live[:3], epsilon=0.3)
        np.testing.assert_array_equal(act[3:6], own)
        act[3:6] = own
        batch.update(Transition(states[s], act, rewards, states[s_next], done, np.zeros(9, bool), live), step)
        lone.update(
            Transition(states[s[:3]], own, rewards[:3], states[s_next[:3]], done[:3], np.zeros(3, bool), live[:3]), step
        )
    for k in range(3):
        mine, theirs = batch.agent_tensors(3 + k), lone.agent_tensors(k)
        np.testing.assert_array_equal(mine["values"], theirs["values"])
        np.testing.assert_array_equal(mine["keys"], theirs["keys"])


def test_the_table_grows_past_its_first_room_and_keeps_every_value():
    learner = TabularLearner(2, [("position", 300)], 2, AgentConfig(algorithm=Algorithm.qlearning, lr=1.0), seed=0)
    states = np.eye(300, dtype=np.float32)
    for n in range(300):  # agent 0 sees state n, agent 1 state 299 - n; reward n ends the episode
        obs = np.stack([states[n], states[299 - n]])
        learner.update(
            Transition(
                obs, np.array([1, 0]), np.array([n, -n]), obs, np.ones(2, bool), np.zeros(2, bool), np.ones(2, bool)
            ),
            n + 1,
        )
    assert learner.index.num_states[0] == 300 and learner.q.shape[1] >= 300
    table0, table1 = learner.agent_tensors(0), learner.agent_tensors(1)
    np.testing.assert_array_equal(table0["keys"], states)  # in the order agent 0 updated them
    np.testing.assert_array_equal(table0["values"][:, 1], np.arange(300))
    np.testing.assert_array_equal(table1["keys"], states[::-1])
    np.testing.assert_array_equal(table1["values"][:, 0], -np.arange(300))


def test_a_draw_is_the_documented_splitmix64_construction_worked_in_plain_integers():
    mask, golden = 2**64 - 1, 0x9E3779B97F4A7C15

    def splitmix(seed: int, position: int) -> int:  # output number position + 1 of SplitMix64(seed)
        z = (seed + (position + 1) * golden) & mask
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & mask
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
        return z ^ (z >> 31)

    seed, stream, agent, counter = 12345, 2, 3, 987
    key = splitmix(splitmix(seed, stream), agent)
    expected = [(splitmix(splitmix(key, counter), slot) >> 11) * 2.0**-53 for slot in range(3)]
    assert draws(seed, stream, counter, [agent])[0].tolist() == expected
