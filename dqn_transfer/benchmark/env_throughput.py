"""Section 1, environment throughput: joint steps per second with random actions, resets included.

The same pre-drawn actions are played twice: through the PettingZoo ``ParallelEnv`` API (dicts in and
out, what a PettingZoo user pays) and through the numpy core directly (what the trainer pays). Both
start from the same seed, so they play the same episodes; drawing the actions up front keeps the
action sampler out of the timing.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dqn_transfer.benchmark.config import BENCH_MAP
from dqn_transfer.enums import Mode
from dqn_transfer.envs.treasure_hunt import parallel_env
from dqn_transfer.timing import Stopwatch


def measure_env_throughput(num_agents: int, steps: int, seed: int) -> dict[str, Any]:
    """``steps`` joint steps of competitive random play on ``BENCH_MAP`` generated for ``num_agents`` starts."""
    env = parallel_env(num_agents=num_agents, mode=Mode.competitive, **BENCH_MAP)
    actions = np.random.default_rng(seed).integers(0, env.game.num_actions, size=(steps, num_agents))
    index = {name: i for i, name in enumerate(env.possible_agents)}
    env.reset(seed=seed)
    api_episodes = 0
    with Stopwatch() as api:
        for row in actions.tolist():
            if not env.agents:
                env.reset()
                api_episodes += 1
            env.step({name: row[index[name]] for name in env.agents})

    game, rng = env.game, np.random.default_rng(seed)  # the seed env.reset(seed=seed) used
    game.reset(rng)
    core_episodes = 0
    with Stopwatch() as core:
        for row in actions:
            if game.done:
                game.reset(rng)
                core_episodes += 1
            game.step(row)
    return {
        "num_agents": num_agents,
        "mode": Mode.competitive.value,
        "steps": steps,
        "pettingzoo_episodes": api_episodes,
        "core_episodes": core_episodes,
        "pettingzoo_steps_per_s": steps / api.wall,
        "core_steps_per_s": steps / core.wall,
        "pettingzoo_steps_per_cpu_s": steps / api.cpu,
        "core_steps_per_cpu_s": steps / core.cpu,
    }
