"""The torch engine's gradient step, hand-written backward against autograd, side by side in one process
(``python scripts/time_dqn_backward.py``).

R = 10 replicas (``--replicas``) x K = 4 agents (40 networks), batch 64 per agent, hidden [64, 64], the default game's
observation (38) and actions (4), one torch thread (``threads``' default). Three variants of
``DQNLearner.train_on`` on the same replay batch:

- ``hand``: the engine as it is (``BatchedMLP.backward``, per-member clip, ``FlatAdam``);
- ``autograd``: ``loss.backward()`` through ``BatchedMLP.forward`` instead, then the same clip and
  ``FlatAdam``;
- ``autograd+adam``: ``loss.backward()``, the same per-member clip, and ``torch.optim.Adam`` over the
  flat parameter.

Each repeat times every variant in turn (interleaved, so a loaded machine slows all alike) for
``steps`` steps after one untimed step; prints the median and the best µs per gradient step.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch

from dqn_transfer.agents import DQNLearner, Experience, ReplayBatch
from dqn_transfer.agents.dqn_update import double_dqn_targets, dqn_targets, huber
from dqn_transfer.config import AgentConfig

K, B, HIDDEN, LAYOUT, A = 4, 64, [64, 64], [("position", 36), ("treasures", 2)], 4


def learner_and_batch(replicas: int) -> tuple[DQNLearner, ReplayBatch]:
    """A learner of ``replicas`` x K agents with a replay batch of random transitions it has learnt from."""
    learner = DQNLearner(K, LAYOUT, A, AgentConfig(hidden=HIDDEN, batch_size=B), seed=list(range(replicas)))
    rng = np.random.default_rng(0)
    rows, d = learner.num_rows, learner.obs_dim
    data = ReplayBatch(
        rng.random((rows, B, d), dtype=np.float32),
        rng.integers(0, A, (rows, B)),
        rng.normal(size=(rows, B)).astype(np.float32),
        rng.random((rows, B, d), dtype=np.float32),
        (rng.random((rows, B)) < 0.1).astype(np.float32),
    )
    for row in range(rows):
        learner.learn_from(row, Experience(*(field[row] for field in data)))
    return learner, data


def autograd_step(learner: DQNLearner, batch: ReplayBatch, adam: torch.optim.Optimizer | None) -> None:
    """The engine's step with autograd for the gradient (and ``adam``, if given, for the step)."""
    obs, actions, rewards, next_obs, terminated = (torch.from_numpy(field) for field in batch)
    network = learner.q_network
    with torch.no_grad():
        next_q_target = learner._q_values(learner.target_network, next_obs)
        if learner.double:
            next_q_online = learner._q_values(network, next_obs)
            targets = double_dqn_targets(rewards, next_q_online, next_q_target, terminated, learner.gamma)
        else:
            targets = dqn_targets(rewards, next_q_target, terminated, learner.gamma)
    q_taken = network(obs).gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    weights = torch.from_numpy(learner.loss_weights(learner.replay.size > 0))
    network.flat.grad = None
    (weights * huber(q_taken - targets).mean(dim=1)).sum().backward()
    with torch.no_grad():
        network.flat_grad.copy_(network.flat.grad)
        network.clip_grad_norm_(learner.max_grad_norm)
        if adam is None:
            learner.optimizer.step(list(range(len(network.spans))))
        else:
            network.flat.grad.copy_(network.flat_grad)
            adam.step()


def time_per_step(step: Callable[[], object], steps: int) -> float:
    """µs per call of ``step`` over ``steps`` calls, after one untimed call."""
    step()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return 1e6 * (time.perf_counter() - start) / steps


def measure(replicas: int, repeats: int, steps: int) -> dict[str, list[float]]:
    """µs per gradient step of each variant (``hand``, ``autograd``, ``autograd+adam``), one value per repeat;
    each repeat times every variant in turn, so a loaded machine slows all alike (at the caller's torch thread
    count: the script sets one)."""
    learners = {name: learner_and_batch(replicas) for name in ("hand", "autograd", "autograd+adam")}
    adam = torch.optim.Adam([learners["autograd+adam"][0].q_network.flat], lr=1e-3)
    variants: dict[str, Callable[[], object]] = {
        "hand": lambda: learners["hand"][0].train_on(learners["hand"][1]),
        "autograd": lambda: autograd_step(*learners["autograd"], None),
        "autograd+adam": lambda: autograd_step(*learners["autograd+adam"], adam),
    }
    times: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(repeats):
        for name, step in variants.items():
            times[name].append(time_per_step(step, steps))
    return times
