"""The batched M-member MLP is M ordinary MLPs: same outputs, same gradients, same clipping."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from dqn_transfer.agents import BatchedMLP

K, B, IN, HIDDEN, OUT = 3, 8, 5, [7, 6], 4


def separate_networks(batched: BatchedMLP) -> list[nn.Sequential]:
    """K nn.Sequential(Linear, ReLU, Linear, ReLU, Linear) loaded with the members' weights."""
    networks = []
    for m in range(batched.num_members):
        net = nn.Sequential(nn.Linear(IN, 7), nn.ReLU(), nn.Linear(7, 6), nn.ReLU(), nn.Linear(6, OUT))
        state = batched.member_state(m)
        # Sequential numbers its modules 0..4; the Linear layers are modules 0, 2, 4.
        net.load_state_dict(
            {
                f"{2 * l}.{kind}": torch.from_numpy(state[f"layers.{l}.{kind}"])
                for l in range(3)
                for kind in ("weight", "bias")
            }
        )
        networks.append(net)
    return networks


def make_batch(seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(K, B, IN, generator=g), torch.randn(K, B, OUT, generator=g)


def autograd_grads(batched: BatchedMLP, x: torch.Tensor, y: torch.Tensor) -> list[torch.Tensor]:
    """The learner's reduction (sum over members of each member's mean loss), through autograd."""
    batched.zero_grad()
    F.smooth_l1_loss(batched(x), y, reduction="none").mean(dim=(1, 2)).sum().backward()
    return [tensor.grad for tensor in batched.tensors]


def test_outputs_and_gradients_match_separate_networks():
    batched = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(0)])
    networks = separate_networks(batched)
    x, y = make_batch()
    out = batched(x)
    grads = autograd_grads(batched, x, y)
    for m, net in enumerate(networks):
        out_m = net(x[m])
        torch.testing.assert_close(out[m], out_m)
        F.smooth_l1_loss(out_m, y[m]).backward()
        for l in range(3):
            torch.testing.assert_close(grads[2 * l][m], net[2 * l].weight.grad.t())
            torch.testing.assert_close(grads[2 * l + 1][m], net[2 * l].bias.grad)


def test_gradient_clipping_is_per_member_like_clip_grad_norm():
    batched = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(0)])
    networks = separate_networks(batched)
    x, y = make_batch()
    y[0] *= 100.0  # member 0 gets a huge gradient; it must not shrink the others' steps

    F.mse_loss(batched(x), y, reduction="none").mean(dim=(1, 2)).sum().backward()
    batched.clip_grad_norm_(5.0)
    for m, net in enumerate(networks):
        F.mse_loss(net(x[m]), y[m]).backward()
        norm = torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
        assert (norm > 5.0) == (m == 0)  # only member 0 is clipped
        for l in range(3):
            torch.testing.assert_close(batched.layer(l)[0].grad[m], net[2 * l].weight.grad.t())
            torch.testing.assert_close(batched.layer(l)[1].grad[m], net[2 * l].bias.grad)


def test_gradients_below_the_clip_norm_are_left_exactly_as_they_are():
    batched = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(0)])
    x, y = make_batch()
    before = [grad.clone() for grad in autograd_grads(batched, x, y)]
    batched.clip_grad_norm_(1e6)
    assert all(torch.equal(tensor.grad, grad) for tensor, grad in zip(batched.tensors, before))


def test_a_frozen_tensor_is_not_clipped():
    batched = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(0)])
    batched.layer(0)[0].requires_grad_(False)
    x, y = make_batch()
    F.mse_loss(batched(x), y, reduction="none").mean(dim=(1, 2)).sum().backward()
    batched.clip_grad_norm_(1e-3)
    assert batched.layer(0)[0].grad is None
    for m in range(K):  # the norm of the tensors with a gradient is clipped to 1e-3
        norm = torch.stack([t.grad[m].norm() for t in batched.tensors[1:]]).norm()
        assert float(norm) == pytest.approx(1e-3, rel=1e-4)


def test_same_generator_seed_gives_same_weights_and_nn_linear_bounds():
    a = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(3)])
    b = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(3)])
    assert all(torch.equal(t_a, t_b) for t_a, t_b in zip(a.tensors, b.tensors))
    # nn.Linear's default init: U(-1/sqrt(in), 1/sqrt(in)); layer 0 has in = 5 -> bound 0.447
    weight_0 = a.layer(0)[0]
    assert weight_0.abs().max() <= 5**-0.5
    assert not torch.equal(weight_0[0], weight_0[1])  # members start different


def test_one_generator_per_block_gives_each_block_its_lone_weights():
    seeds = [7, 8]
    joint = BatchedMLP(2 * K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(s) for s in seeds])
    for r, seed in enumerate(seeds):
        lone = BatchedMLP(K, IN, HIDDEN, OUT, [torch.Generator().manual_seed(seed)])
        for t_joint, t_lone in zip(joint.tensors, lone.tensors):
            assert torch.equal(t_joint[r * K : (r + 1) * K], t_lone)


def test_member_state_round_trip_and_polyak_update():
    a = BatchedMLP(2, IN, HIDDEN, OUT, [torch.Generator().manual_seed(0)])
    b = BatchedMLP(2, IN, HIDDEN, OUT, [torch.Generator().manual_seed(1)])
    b.load_member_state(1, a.member_state(0))
    for name, tensor in a.member_state(0).items():
        assert np.array_equal(b.member_state(1)[name], tensor)

    before = b.layer(2)[1].clone()
    b.update_from(a, tau=0.25)
    # p <- p + 0.25 * (p_source - p)
    torch.testing.assert_close(b.layer(2)[1], before + 0.25 * (a.layer(2)[1] - before))
    b.update_from(a, tau=1.0)
    assert all(torch.equal(t_a, t_b) for t_a, t_b in zip(a.tensors, b.tensors))


def test_a_batched_mlp_refuses_to_be_moved():
    with pytest.raises(TypeError, match="built on its device"):
        BatchedMLP(1, IN, HIDDEN, OUT).to("cpu")
