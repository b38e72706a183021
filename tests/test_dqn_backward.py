"""The backward timing's variants do the same step: what `scripts/time_dqn_backward.py` times side by side is
one gradient step taken three ways, not three different computations."""

import torch

from dqn_transfer.benchmark.dqn_backward import autograd_step, learner_and_batch, measure


def test_autograd_and_the_hand_written_backward_take_the_same_step():
    (hand, batch), (auto, same_batch) = learner_and_batch(1), learner_and_batch(1)
    assert torch.equal(hand.q_network.flat, auto.q_network.flat)
    before = hand.q_network.flat.clone()
    hand.train_on(batch)
    autograd_step(auto, same_batch, None)
    assert not torch.equal(hand.q_network.flat, before)  # a step was taken
    torch.testing.assert_close(auto.q_network.flat, hand.q_network.flat, rtol=1e-5, atol=1e-6)


def test_each_variant_is_timed_once_a_repeat():
    times = measure(replicas=1, repeats=2, steps=1)
    assert list(times) == ["hand", "autograd", "autograd+adam"]
    assert all(len(values) == 2 and min(values) > 0 for values in times.values())
