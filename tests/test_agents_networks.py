"""The batched K-member MLP is K ordinary MLPs: same outputs, same gradients, same clipping."""

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
            {f"{2 * l}.{kind}": state[f"layers.{l}.{kind}"] for l in range(3) for kind in ("weight", "bias")}
        )
        networks.append(net)
    return networks


def make_batch(seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(K, B, IN, generator=g), torch.randn(K, B, OUT, generator=g)


def test_outputs_and_gradients_match_separate_networks():
    batched = BatchedMLP(K, IN, HIDDEN, OUT, torch.Generator().manual_seed(0))
    networks = separate_networks(batched)
    x, y = make_batch()

    out = batched(x)
    # The learner's reduction: sum over members of each member's mean loss.
    F.smooth_l1_loss(out, y, reduction="none").mean(dim=(1, 2)).sum().backward()
    for m, net in enumerate(networks):
        out_m = net(x[m])
        torch.testing.assert_close(out[m], out_m)
        F.smooth_l1_loss(out_m, y[m]).backward()
        for l in range(3):
            weight, bias = batched.layer(l)
            torch.testing.assert_close(weight.grad[m], net[2 * l].weight.grad.t())
            torch.testing.assert_close(bias.grad[m], net[2 * l].bias.grad)


def test_gradient_clipping_is_per_member_like_clip_grad_norm():
    batched = BatchedMLP(K, IN, HIDDEN, OUT, torch.Generator().manual_seed(0))
    networks = separate_networks(batched)
    x, y = make_batch()
    y[0] *= 100.0  # member 0 gets a huge gradient; it must not shrink the others' steps

    F.mse_loss(batched(x), y, reduction="none").mean(dim=(1, 2)).sum().backward()
    norms = batched.clip_grad_norm_(0.5)
    for m, net in enumerate(networks):
        F.mse_loss(net(x[m]), y[m]).backward()
        torch.testing.assert_close(norms[m], torch.nn.utils.clip_grad_norm_(net.parameters(), 0.5))
        for l in range(3):
            torch.testing.assert_close(batched.layer(l)[0].grad[m], net[2 * l].weight.grad.t())


def test_same_generator_seed_gives_same_weights_and_nn_linear_bounds():
    a = BatchedMLP(K, IN, HIDDEN, OUT, torch.Generator().manual_seed(3))
    b = BatchedMLP(K, IN, HIDDEN, OUT, torch.Generator().manual_seed(3))
    for p, q in zip(a.parameters(), b.parameters()):
        assert torch.equal(p, q)
    # nn.Linear's default init: U(-1/sqrt(in), 1/sqrt(in)); layer 0 has in = 5 -> bound 0.447
    assert a.weight_0.abs().max() <= 5**-0.5
    assert not torch.equal(a.weight_0[0], a.weight_0[1])  # members start different


def test_member_state_round_trip_and_polyak_update():
    a = BatchedMLP(2, IN, HIDDEN, OUT, torch.Generator().manual_seed(0))
    b = BatchedMLP(2, IN, HIDDEN, OUT, torch.Generator().manual_seed(1))
    b.load_member_state(1, a.member_state(0))
    for name, tensor in a.member_state(0).items():
        assert torch.equal(b.member_state(1)[name], tensor)

    before = b.bias_2.detach().clone()
    b.update_from(a, tau=0.25)
    # p <- p + 0.25 * (p_source - p)
    torch.testing.assert_close(b.bias_2, before + 0.25 * (a.bias_2 - before))
    b.update_from(a, tau=1.0)
    assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters()))
