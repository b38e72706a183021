"""The reference programs of sections 5 and 6, each started as a process of its own by
:mod:`dqn_transfer.benchmark.whole_process`::

    python -m dqn_transfer.benchmark.processes sb3  --steps N --seed S [--map lone|bench] [--learning-starts L]
    python -m dqn_transfer.benchmark.processes bare --steps N --seed S [--map lone|bench] [--learning-starts L]

``sb3``: Stable-Baselines3, ``DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0", **map), ...).learn(N)``.

``bare``: the bare-PyTorch floor, a DQN loop in the manner of CleanRL's ``dqn.py``: plain code that reads
top to bottom (network, optimiser, replay ring buffer, epsilon schedule, the loop), with nothing of ours
but the environment and the hyperparameters. It is what a user could write in an afternoon, so a
whole process of ours slower than it pays for something (or for nothing); it is kept plain on purpose
and must not be optimised past what CleanRL would write.

Both take the hyperparameters of ``LONE_AGENT`` (``learning_starts`` from the command line, since
section 6 fills less replay before training), run on one torch thread (as ``threads=1`` does for ours),
play the map ``--map`` names (``LONE_MAP`` or ``BENCH_MAP``) and print, last, one JSON line of what
they did (steps, gradient steps, episodes): the parent checks it after the process has exited.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import random
import sys
from typing import Any

import gymnasium
import numpy as np
import torch
import torch.nn.functional as F
from gymnasium.spaces import flatdim
from torch import nn

from dqn_transfer.benchmark.config import BENCH_MAP, LONE_AGENT, LONE_MAP, sb3_dqn
from dqn_transfer.config import AgentConfig

# (Importing any dqn_transfer module registers TreasureHunt-v0.)
MAPS = {"lone": LONE_MAP, "bench": BENCH_MAP}


def sb3(steps: int, seed: int, agent: AgentConfig, env_kwargs: dict[str, Any]) -> dict[str, int]:
    """SB3's ``DQN.learn(steps)`` with ``agent``'s hyperparameters under SB3's names (``config.sb3_kwargs``).

    :param steps: env steps to learn for
    :param seed: SB3's seed (networks, exploration, the env)
    :param agent: the hyperparameters
    :param env_kwargs: the map of ``TreasureHunt-v0``
    """
    model = sb3_dqn(agent, env_kwargs, seed)
    model.learn(total_timesteps=steps)
    return {
        "steps": int(model.num_timesteps),
        "gradient_steps": int(model._n_updates),
        "episodes": int(model._episode_num),
    }


def mlp(sizes: list[int]) -> nn.Sequential:
    """``nn.Sequential`` of Linear layers ``sizes[0] -> ... -> sizes[-1]`` with ReLU between them."""
    layers: list[nn.Module] = []
    for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(fan_in, fan_out), nn.ReLU()]
    return nn.Sequential(*layers[:-1])


def linear_schedule(start_e: float, end_e: float, duration: float, t: int) -> float:
    """CleanRL's epsilon schedule: linear from ``start_e`` to ``end_e`` over ``duration`` steps, then held."""
    slope = (end_e - start_e) / duration
    return max(slope * t + start_e, end_e)


def bare(steps: int, seed: int, agent: AgentConfig, env_kwargs: dict[str, Any]) -> dict[str, int]:
    """CleanRL-style DQN on ``TreasureHunt-v0`` for ``steps`` env steps.

    :param steps: env steps to train for
    :param seed: seeds Python, numpy, torch and the env
    :param agent: the hyperparameters
    :param env_kwargs: the map of ``TreasureHunt-v0``
    """
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)

    env = gymnasium.make("TreasureHunt-v0", **env_kwargs)
    obs_dim, num_actions = flatdim(env.observation_space), flatdim(env.action_space)  # a Box [D], Discrete(4)

    # Q-network: Linear/ReLU MLP; the target network starts as a copy.
    q_network = mlp([obs_dim, *agent.hidden, num_actions])
    target_network = copy.deepcopy(q_network)
    optimizer = torch.optim.Adam(q_network.parameters(), lr=agent.lr)

    # Replay: a numpy ring buffer (only `terminated` is stored: a time-limit truncation still has a future).
    capacity = agent.buffer_size
    buffer_obs = np.zeros((capacity, obs_dim), dtype=np.float32)
    buffer_next_obs = np.zeros((capacity, obs_dim), dtype=np.float32)
    buffer_actions = np.zeros(capacity, dtype=np.int64)
    buffer_rewards = np.zeros(capacity, dtype=np.float32)
    buffer_terminated = np.zeros(capacity, dtype=np.float32)
    position, size = 0, 0

    exploration_steps = agent.exploration_fraction * steps
    episodes, gradient_steps = 0, 0
    obs, _ = env.reset(seed=seed)
    for global_step in range(1, steps + 1):
        # Act epsilon-greedily.
        epsilon = linear_schedule(agent.eps_start, agent.eps_end, exploration_steps, global_step)
        if rng.random() < epsilon:
            action = int(rng.integers(num_actions))
        else:
            with torch.no_grad():
                action = int(q_network(torch.as_tensor(obs, dtype=torch.float32)).argmax())
        next_obs, reward, terminated, truncated, _ = env.step(action)

        # Store the transition.
        buffer_obs[position], buffer_next_obs[position] = obs, next_obs
        buffer_actions[position], buffer_rewards[position], buffer_terminated[position] = action, reward, terminated
        position, size = (position + 1) % capacity, min(size + 1, capacity)

        obs = next_obs
        if terminated or truncated:
            episodes += 1
            obs, _ = env.reset()

        # Train: every train_freq steps once learning_starts steps are stored.
        if global_step > agent.learning_starts and global_step % agent.train_freq == 0:
            for _ in range(agent.gradient_steps):
                index = rng.integers(0, size, size=agent.batch_size)
                b_obs, b_next_obs = torch.from_numpy(buffer_obs[index]), torch.from_numpy(buffer_next_obs[index])
                b_actions, b_rewards = torch.from_numpy(buffer_actions[index]), torch.from_numpy(buffer_rewards[index])
                b_terminated = torch.from_numpy(buffer_terminated[index])
                with torch.no_grad():
                    target_max = target_network(b_next_obs).max(dim=1).values
                    td_target = b_rewards + agent.gamma * target_max * (1.0 - b_terminated)
                q_taken = q_network(b_obs).gather(1, b_actions.unsqueeze(1)).squeeze(1)
                loss = F.smooth_l1_loss(q_taken, td_target)
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(q_network.parameters(), agent.max_grad_norm)
                optimizer.step()
                gradient_steps += 1

        # Update the target network (tau = 1.0: a hard copy).
        if global_step % agent.target_update == 0:
            for target_param, param in zip(target_network.parameters(), q_network.parameters()):
                target_param.data.copy_(agent.tau * param.data + (1.0 - agent.tau) * target_param.data)

    env.close()
    return {"steps": steps, "gradient_steps": gradient_steps, "episodes": episodes}


PROGRAMS = {"sb3": sb3, "bare": bare}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dqn_transfer.benchmark.processes",
        description="A reference DQN process of the benchmark (sections 5 and 6).",
    )
    parser.add_argument("program", choices=PROGRAMS)
    parser.add_argument("--steps", type=int, required=True, help="env steps to train for")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--map", choices=MAPS, default="lone", help="LONE_MAP (section 5) or BENCH_MAP (section 6)")
    parser.add_argument(
        "--learning-starts",
        type=int,
        default=LONE_AGENT.learning_starts,
        help=f"env steps before the first update (default {LONE_AGENT.learning_starts})",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    agent = dataclasses.replace(LONE_AGENT, learning_starts=args.learning_starts)
    report = PROGRAMS[args.program](args.steps, args.seed, agent, MAPS[args.map])
    print(json.dumps({"program": args.program, **report}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
