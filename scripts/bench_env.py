"""Environment throughput: joint steps per second with random actions (DESIGN section 7).

``measure_env_throughput`` is called by ``scripts/bench.py``; run this file alone for a small table:

    python scripts/bench_env.py [--steps N] [--seed S]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dqn_transfer.envs.treasure_hunt import parallel_env

BENCH_MAP = dict(size=10, num_treasures=4, num_traps=4, complexity=0.1, map_seed=0)


def measure_env_throughput(
    num_agents: int, steps: int, seed: int, mode: str = "competitive"
) -> dict:
    """Joint steps/s of random play on a 10 x 10 map (complexity 0.1), resets included.

    ``joint_steps_per_s`` goes through the PettingZoo ``ParallelEnv`` API (dicts in and out);
    ``core_steps_per_s`` drives the numpy game directly, as the trainer does. Actions are drawn
    up front so the timing measures the environment, not the action sampler.
    """
    env = parallel_env(num_agents=num_agents, mode=mode, **BENCH_MAP)
    actions = np.random.default_rng(seed).integers(0, 4, size=(steps, num_agents))
    index = {name: i for i, name in enumerate(env.possible_agents)}
    env.reset(seed=seed)
    episodes = 0
    start = time.perf_counter()
    for row in actions.tolist():
        if not env.agents:
            env.reset()
            episodes += 1
        env.step({name: row[index[name]] for name in env.agents})
    api_seconds = time.perf_counter() - start

    game, rng = env.game, np.random.default_rng(seed)
    game.reset(rng)
    start = time.perf_counter()
    for row in actions:
        if game.done:
            game.reset(rng)
        game.step(row)
    core_seconds = time.perf_counter() - start
    return {
        "num_agents": num_agents,
        "mode": mode,
        "steps": steps,
        "episodes": episodes,
        "joint_steps_per_s": steps / api_seconds,
        "core_steps_per_s": steps / core_seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    header = ("agents", "mode", "PettingZoo steps/s", "core steps/s", "episodes")
    print("{:>6} {:>12} {:>19} {:>13} {:>9}".format(*header))
    for mode in ("competitive", "deliberative"):
        for num_agents in (1, 4, 8):
            r = measure_env_throughput(num_agents, args.steps, args.seed, mode)
            print(f"{num_agents:>6} {mode:>12} {r['joint_steps_per_s']:>19,.0f} "
                  f"{r['core_steps_per_s']:>13,.0f} {r['episodes']:>9}")


if __name__ == "__main__":
    main()
