"""Section 4, time per gradient update (K = 1), on the single-agent task's shapes.

- ``bare``: a CleanRL-style update of an ``nn.Sequential`` (Linear/ReLU) on a batch already in memory
  as tensors: target max under no_grad, gather, Huber loss, backward, ``clip_grad_norm_``, Adam step.
  The floor PyTorch gives for this work.
- ``in_memory``: ``DQNLearner.train_on(batch)``, our update (autograd over the stacked networks,
  per-member clip, ``torch.optim.Adam``, per-agent loss/Q statistics) on the same batch in memory.
- ``ours``: ``DQNLearner.gradient_step()``: replay sample + ``in_memory``.
- ``sample``: ``ReplayBuffer.sample`` alone (part of ``ours``).
- ``sb3``: SB3's ``DQN.train``, per gradient step (its replay sample included).

Every variant learns from the same kind of replay: real transitions of random play, as many as
``replay_warmup`` asks (untimed). Each timing is preceded by one untimed call (first-call allocations).
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from dqn_transfer.agents import DQNLearner, ReplayBatch, Transition, dqn_targets
from dqn_transfer.benchmark.config import BENCH_AGENT, SOURCE_MAP, replay_warmup, sb3_dqn
from dqn_transfer.benchmark.processes import mlp
from dqn_transfer.config import AgentConfig
from dqn_transfer.envs import make_game
from dqn_transfer.timing import Stopwatch

UPDATE_NAMES = ("bare", "in_memory", "ours", "sample", "sb3")
THREAD_NAMES = ("bare", "ours")  # also timed at torch's default thread count


def time_calls(fn: Callable[[], Any], calls: int, max_seconds: float | None = None) -> tuple[float, float]:
    """(wall, CPU) microseconds per call of ``fn``: the mean over ``calls`` calls, or over those done
    within ``max_seconds`` if that comes first. One untimed call first."""
    fn()
    deadline = math.inf if max_seconds is None else time.perf_counter() + max_seconds
    done = 0
    with Stopwatch() as watch:
        while done < calls:
            fn()
            done += 1
            if time.perf_counter() > deadline:
                break
    return 1e6 * watch.wall / done, 1e6 * watch.cpu / done


class UpdateRig:
    """Our learner and the two bare updates, on replay filled by random play (see the module docstring)."""

    def __init__(self, seed: int, agent: AgentConfig = BENCH_AGENT, env_kwargs: dict[str, Any] = SOURCE_MAP):
        game = make_game(**env_kwargs).single_agent_game()
        self.agent = agent
        self.learner = DQNLearner(1, game.obs_layout(), game.num_actions, agent, seed=seed)
        rng = np.random.default_rng(seed)
        obs, live = game.reset(rng), np.ones(1, dtype=bool)
        for _ in range(replay_warmup(agent)):
            actions = rng.integers(0, game.num_actions, size=1)
            next_obs, rewards, terminated, truncated, *_ = game.step(actions)
            self.learner.replay.add(Transition(obs, actions, rewards, next_obs, terminated, truncated, live))
            obs = game.reset(rng) if game.done else next_obs
        self.batch = self.learner.replay.sample(agent.batch_size)  # [1, B, ...]
        self.flat_batch = ReplayBatch(*(torch.from_numpy(field[0]) for field in self.batch))  # type: ignore[arg-type]  # [B, ...], for torch

        torch.manual_seed(seed)
        self.q = mlp([game.obs_dim, *agent.hidden, game.num_actions])
        self.q_target = copy.deepcopy(self.q).requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.q.parameters(), lr=agent.lr)

    def bare_update(self) -> None:
        """One CleanRL-style DQN gradient step of the ``nn.Sequential`` on the batch in memory."""
        batch = self.flat_batch
        with torch.no_grad():
            td_target = dqn_targets(batch.rewards, self.q_target(batch.next_obs), batch.terminated, self.agent.gamma)
        q_taken = self.q(batch.obs).gather(-1, batch.actions.unsqueeze(-1)).squeeze(-1)  # type: ignore[attr-defined]  # a torch batch here
        loss = F.smooth_l1_loss(q_taken, td_target)
        self.optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.q.parameters(), self.agent.max_grad_norm)
        self.optimizer.step()

    def time(self, which: str, updates: int, max_seconds: float | None = None) -> tuple[float, float]:
        """(wall, CPU) microseconds per update of ``which`` in (bare, in_memory, ours, sample)."""
        fn = {
            "bare": self.bare_update,
            "in_memory": lambda: self.learner.train_on(self.batch),
            "ours": self.learner.gradient_step,
            "sample": lambda: self.learner.replay.sample(self.agent.batch_size),
        }[which]
        return time_calls(fn, updates, max_seconds)


class SB3UpdateRig:
    """SB3 ``DQN.train`` per gradient step, on replay filled by ``learn`` for ``replay_warmup`` steps
    (which do not train while they are within ``learning_starts``)."""

    def __init__(self, seed: int, agent: AgentConfig = BENCH_AGENT, env_kwargs: dict[str, Any] = SOURCE_MAP):
        self.model = sb3_dqn(agent, env_kwargs, seed)
        self.model.learn(total_timesteps=replay_warmup(agent))
        self.batch_size = agent.batch_size

    def time(self, updates: int) -> tuple[float, float]:
        """(wall, CPU) microseconds per gradient step (one ``train`` call of ``updates`` steps)."""
        self.model.train(gradient_steps=1, batch_size=self.batch_size)
        with Stopwatch() as watch:
            self.model.train(gradient_steps=updates, batch_size=self.batch_size)
        return 1e6 * watch.wall / updates, 1e6 * watch.cpu / updates
