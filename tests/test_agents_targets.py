"""Bootstrapped targets (of tensors and numpy arrays alike), the epsilon schedule and epsilon-greedy,
checked against hand arithmetic."""

import numpy as np
import pytest
import torch

from dqn_transfer.agents import double_dqn_targets, dqn_targets, epsilon_greedy, linear_schedule

GAMMA = 0.9
# Three transitions, two actions. Rows: a normal step, a step where DQN and Double DQN disagree
# twice over, and a terminal step.
REWARDS = torch.tensor([1.0, 0.0, 2.0])
NEXT_Q_ONLINE = torch.tensor([[1.0, 3.0], [2.0, 0.0], [5.0, 4.0]])
NEXT_Q_TARGET = torch.tensor([[4.0, 2.0], [1.0, 6.0], [3.0, 7.0]])
TERMINATED = torch.tensor([False, False, True])


def test_dqn_targets_take_the_target_networks_max():
    y = dqn_targets(REWARDS, NEXT_Q_TARGET, TERMINATED, GAMMA)
    expected = torch.tensor(
        [
            4.6,  # 1 + 0.9 * max(4, 2) = 1 + 3.6
            5.4,  # 0 + 0.9 * max(1, 6)
            2.0,  # terminated: r only
        ]
    )
    torch.testing.assert_close(y, expected)


def test_double_dqn_targets_score_the_online_argmax_with_the_target_network():
    y = double_dqn_targets(REWARDS, NEXT_Q_ONLINE, NEXT_Q_TARGET, TERMINATED, GAMMA)
    expected = torch.tensor(
        [
            2.8,  # online argmax = 1 -> Q_target = 2 -> 1 + 0.9 * 2 (DQN said 4.6)
            0.9,  # online argmax = 0 -> Q_target = 1 -> 0 + 0.9 * 1 (DQN said 5.4)
            2.0,  # terminated: r only
        ]
    )
    torch.testing.assert_close(y, expected)


def test_truncation_bootstraps_and_termination_does_not():
    # The same transition (r = 1, max Q_target(s') = 4) ending by time limit vs. by termination.
    # Truncation is not termination: only the terminated flag reaches the target.
    rewards = torch.tensor([1.0, 1.0])
    next_q = torch.tensor([[4.0, 2.0], [4.0, 2.0]])
    terminated = torch.tensor([False, True])  # row 0 was truncated, row 1 terminated
    torch.testing.assert_close(dqn_targets(rewards, next_q, terminated, GAMMA), torch.tensor([4.6, 1.0]))
    torch.testing.assert_close(double_dqn_targets(rewards, next_q, next_q, terminated, GAMMA), torch.tensor([4.6, 1.0]))


def test_targets_work_on_batched_agent_shapes():
    # [K=2, B=1, A=2]: the learner calls the functions on all agents' batches at once.
    y = dqn_targets(
        torch.tensor([[0.0], [1.0]]), torch.tensor([[[1.0, 2.0]], [[3.0, 0.0]]]), torch.tensor([[False], [False]]), 0.5
    )
    torch.testing.assert_close(y, torch.tensor([[1.0], [2.5]]))  # 0 + 0.5*2 ; 1 + 0.5*3


def test_targets_of_numpy_arrays_are_the_targets_of_tensors():
    """The targets are array-generic (the numpy engine calls the same functions): same values, float32."""
    rewards, online, target, terminated = (t.numpy() for t in (REWARDS, NEXT_Q_ONLINE, NEXT_Q_TARGET, TERMINATED))
    for got, want in [
        (dqn_targets(rewards, target, terminated, GAMMA), dqn_targets(REWARDS, NEXT_Q_TARGET, TERMINATED, GAMMA)),
        (
            double_dqn_targets(rewards, online, target, terminated, GAMMA),
            double_dqn_targets(REWARDS, NEXT_Q_ONLINE, NEXT_Q_TARGET, TERMINATED, GAMMA),
        ),
    ]:
        assert isinstance(got, np.ndarray) and got.dtype == np.float32
        np.testing.assert_array_equal(got, want.numpy())


@pytest.mark.parametrize(
    ("t", "expected"),
    [
        (0, 1.0),
        (50, 0.525),  # 1 + (50/100) * (0.05 - 1) = 1 - 0.475
        (100, 0.05),
        (250, 0.05),  # held at the end value
    ],
)
def test_linear_schedule(t, expected):
    assert linear_schedule(1.0, 0.05, 100, t) == pytest.approx(expected)


def test_linear_schedule_with_zero_duration_is_already_at_the_end():
    assert linear_schedule(1.0, 0.1, 0, 0) == pytest.approx(0.1)


def test_epsilon_greedy_extremes():
    greedy = np.full(1000, 2)
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(epsilon_greedy(greedy, 0.0, 4, rng), greedy)
    explored = epsilon_greedy(greedy, 1.0, 4, rng)
    assert set(explored.tolist()) == {0, 1, 2, 3}
    assert explored.dtype == np.int64
