"""Each engine's gradient step is ``dqn_reference.reference_update``'s: the same losses, clipped gradients
and updated weights, computed by plain ``nn.Sequential`` networks, autograd and ``torch.optim.Adam``
from the same weights on the same batches (R = 2 replicas of K = 2 agents, one network per agent or
one per replica)."""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
import pytest
import torch
from dqn_reference import reference_update
from torch import nn

from dqn_transfer.agents import DQNLearner, Experience, ReplayBatch
from dqn_transfer.agents.numpy_dqn import NumpyDQNLearner
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm

LAYOUT = [("position", 5), ("treasures", 3)]
D, A, K, SEEDS, B = 8, 4, 2, [3, 4], 16
RTOL, ATOL = 1e-5, 1e-6
ENGINES: dict[str, type[DQNLearner | NumpyDQNLearner]] = {"torch": DQNLearner, "numpy": NumpyDQNLearner}
Learner: TypeAlias = DQNLearner | NumpyDQNLearner


def batch(rows: int, seed: int) -> ReplayBatch:
    """Random transitions, a third of them terminated; rewards wide enough for both sides of the Huber kink."""
    rng = np.random.default_rng(seed)
    return ReplayBatch(
        rng.random((rows, B, D), dtype=np.float32),
        rng.integers(0, A, (rows, B)),
        (3.0 * rng.normal(size=(rows, B))).astype(np.float32),
        rng.random((rows, B, D), dtype=np.float32),
        (rng.random((rows, B)) < 0.3).astype(np.float32),
    )


def sequential(sizes: list[int], state: dict[str, np.ndarray]) -> nn.Sequential:
    """An ``nn.Sequential`` of Linear/ReLU layers holding a member's weights (``nn.Linear`` layout)."""
    layers: list[nn.Module] = []
    for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(fan_in, fan_out), nn.ReLU()]
    network = nn.Sequential(*layers[:-1])
    network.load_state_dict(
        {
            f"{2 * l}.{kind}": torch.from_numpy(state[f"layers.{l}.{kind}"])
            for l in range(len(sizes) - 1)
            for kind in ("weight", "bias")
        }
    )
    return network


def linear_layers(network: nn.Sequential) -> list[nn.Linear]:
    return [module for module in network if isinstance(module, nn.Linear)]


class Reference:
    """One ``nn.Sequential`` online / target pair and ``torch.optim.Adam`` per member of ``learner``."""

    def __init__(self, learner: Learner, double: bool) -> None:
        self.learner, self.double = learner, double
        sizes = learner.q_network.sizes
        self.online = [sequential(sizes, learner.q_network.member_state(m)) for m in range(learner.num_members)]
        self.target = [sequential(sizes, learner.target_network.member_state(m)) for m in range(learner.num_members)]
        for network in self.online:
            for l in learner.frozen_layers:
                linear_layers(network)[l].requires_grad_(False)
        self.optimizers = [torch.optim.Adam(network.parameters(), lr=learner.lr) for network in self.online]

    def step(self, replay_batch: ReplayBatch) -> tuple[np.ndarray, np.ndarray]:
        """``reference_update`` for every member on its agents' rows; each agent's (loss, mean Q)."""
        learner, per_member = self.learner, learner_rows_per_member(self.learner)
        weights = torch.from_numpy(learner.loss_weights(learner.replay.size > 0))
        losses, q_means = [], []
        for m, (online, target, optimizer) in enumerate(zip(self.online, self.target, self.optimizers)):
            rows = slice(m * per_member, (m + 1) * per_member)
            fields = tuple(torch.from_numpy(field[rows]) for field in replay_batch)
            loss, q_mean = reference_update(
                online,
                target,
                optimizer,
                fields,
                weights[rows],
                gamma=learner.gamma,
                double=self.double,
                max_grad_norm=learner.max_grad_norm,
            )
            losses.append(loss.numpy())
            q_means.append(q_mean.numpy())
        return np.concatenate(losses), np.concatenate(q_means)


def learner_rows_per_member(learner: Learner) -> int:
    return learner.num_agents if learner.share_parameters else 1


def stacked_grad(learner: Learner, i: int) -> np.ndarray:
    """The gradient of stacked tensor i ``[M, ...]`` (zeros where the engine computed none)."""
    if isinstance(learner, NumpyDQNLearner):
        return learner.q_network.grads[i]
    grad = learner.q_network.tensors[i].grad
    return np.zeros(learner.q_network.shapes[i], np.float32) if grad is None else grad.numpy()


def make(engine: str, max_grad_norm: float, **kwargs) -> Learner:
    hp = AgentConfig(hidden=[16, 16], batch_size=B, buffer_size=32, lr=1e-2, max_grad_norm=max_grad_norm, **kwargs)
    learner = ENGINES[engine](K, LAYOUT, A, hp, seed=SEEDS)
    # A target network unlike the online one (otherwise Double DQN's target would be DQN's).
    learner.target_network.update_from(ENGINES[engine](K, LAYOUT, A, hp, seed=[7, 8]).q_network, tau=1.0)
    data = batch(1, seed=99)
    for row in range(learner.num_rows - 1):  # the last row has no data yet: its loss weight is 0
        learner.learn_from(row, Experience(*(field[0] for field in data)))
    return learner


def check_against_reference(learner: Learner, clip_active: bool, double: bool | None = None, steps: int = 3) -> None:
    """``steps`` training steps of ``learner`` and of the reference (DQN or Double DQN as the learner, or as
    ``double`` says), compared after each."""
    reference = Reference(learner, learner.double if double is None else double)
    valid = learner.replay.size > 0
    for step in range(steps):
        replay_batch = batch(learner.num_rows, seed=step)
        stats = learner.train_on(replay_batch)
        losses, q_means = reference.step(replay_batch)
        np.testing.assert_allclose(stats.td_loss[valid], losses[valid], rtol=RTOL, err_msg=f"step {step}")
        np.testing.assert_allclose(stats.q_mean[valid], q_means[valid], rtol=RTOL, atol=ATOL, err_msg=f"step {step}")
        assert np.isnan(stats.td_loss[~valid]).all()
        for m, online in enumerate(reference.online):
            layers = linear_layers(online)
            norm = torch.cat([p.grad.reshape(-1) for p in online.parameters() if p.grad is not None]).norm()
            rows = learner_rows_per_member(learner)
            if not valid[m * rows : (m + 1) * rows].any():  # no data, no loss: a zero gradient
                assert float(norm) == 0.0
            elif clip_active:  # the clip applies to each network separately, so every one is at max_grad_norm
                assert float(norm) == pytest.approx(learner.max_grad_norm, rel=1e-4), (step, m)
            else:
                assert float(norm) < learner.max_grad_norm
            weights = learner.q_network.member_state(m)
            for l, layer in enumerate(layers):
                grad_w, grad_b = stacked_grad(learner, 2 * l)[m], stacked_grad(learner, 2 * l + 1)[m]
                if l in learner.frozen_layers:
                    assert layer.weight.grad is None
                    assert not np.asarray(grad_w).any()
                else:
                    assert layer.weight.grad is not None and layer.bias.grad is not None
                    np.testing.assert_allclose(np.asarray(grad_w).T, layer.weight.grad.numpy(), rtol=RTOL, atol=ATOL)
                    np.testing.assert_allclose(np.asarray(grad_b), layer.bias.grad.numpy(), rtol=RTOL, atol=ATOL)
                np.testing.assert_allclose(
                    weights[f"layers.{l}.weight"], layer.weight.detach().numpy(), rtol=RTOL, atol=ATOL
                )
                np.testing.assert_allclose(
                    weights[f"layers.{l}.bias"], layer.bias.detach().numpy(), rtol=RTOL, atol=ATOL
                )


@pytest.mark.parametrize("engine", sorted(ENGINES))
@pytest.mark.parametrize("algorithm", [Algorithm.dqn, Algorithm.double_dqn])
@pytest.mark.parametrize(("max_grad_norm", "clip_active"), [(1e-3, True), (1e3, False)])
def test_an_engines_step_is_the_reference_update(engine, algorithm, max_grad_norm, clip_active):
    check_against_reference(make(engine, max_grad_norm, algorithm=algorithm), clip_active)


@pytest.mark.parametrize("engine", sorted(ENGINES))
def test_a_shared_network_steps_as_the_reference_does_for_its_replicas_agents(engine):
    check_against_reference(make(engine, 1e-3, share_parameters=True), clip_active=True)


@pytest.mark.parametrize("engine", sorted(ENGINES))
def test_a_frozen_layer_is_neither_clipped_nor_stepped_as_in_the_reference(engine):
    learner = make(engine, 1e-3)
    learner.freeze([0])
    check_against_reference(learner, clip_active=True)


def test_the_comparison_fails_for_the_wrong_target():
    """The reference can tell DQN's target from Double DQN's: these tests can fail."""
    for engine in ENGINES:
        with pytest.raises(AssertionError):
            check_against_reference(make(engine, 1e3, algorithm=Algorithm.dqn), clip_active=False, double=True, steps=1)
