"""What the measurements share: the matched hyperparameters, the maps, and SB3's side of the match.

Stable-Baselines3 is optional (the ``dev`` extra), so it is imported only inside :func:`sb3_dqn`, which
only the SB3 measurements call.
"""

from __future__ import annotations

from typing import Any

import gymnasium

from dqn_transfer.config import SB3_NAMES, AgentConfig
from dqn_transfer.enums import Algorithm

# The hyperparameters of every measurement, ours and SB3's (SB3 is given these values, not its own
# defaults: see sb3_kwargs). All but the target update are the CLI's defaults (AgentConfig). SB3's DQN
# updates its target by a hard copy (tau = 1.0) where our default is a soft update every step, so both
# use the hard copy; every 500 steps rather than SB3's default 10,000, so that runs of 2,000-10,000
# steps update the target several times.
BENCH_AGENT = AgentConfig(algorithm=Algorithm.dqn, target_update=500, tau=1.0)

# Sections 1 and 3: a 10 x 10, complexity 0.1 map with 4 chests and 4 traps, generated for K starts.
BENCH_MAP: dict[str, Any] = dict(size=10, num_treasures=4, num_traps=4, complexity=0.1, map_seed=0)
# Sections 2 and 4, the single-agent task: the same map family with one chest 6 moves from the start,
# so an episode is a real navigation problem (on BENCH_MAP agent 0 starts next to a chest: every
# episode would last one step).
SOURCE_MAP: dict[str, Any] = dict(size=10, num_treasures=1, num_traps=1, complexity=0.1, map_seed=2)

# Sections 5 and 6, whole processes: the settings of a small CleanRL-sized run (CleanRL's dqn.py
# trains every 4 steps on batches of 32 with lr 1e-4 and hard target copies), so that the processes
# measured are the ones a user would start, not the in-process rigs of sections 2-4. The rest
# (gamma, epsilon schedule, gradient clip) are AgentConfig's defaults.
LONE_AGENT = AgentConfig(
    algorithm=Algorithm.dqn,
    lr=1e-4,
    batch_size=32,
    buffer_size=50_000,
    learning_starts=1_000,
    train_freq=4,
    gradient_steps=1,
    target_update=1_000,
    tau=1.0,
    hidden=[64, 64],
)
# Section 5: a 7 x 7 map with one chest (agent 0 alone: num_agents defaults to the one chest).
LONE_MAP: dict[str, Any] = dict(size=7, num_treasures=1, num_traps=1, complexity=0.15, map_seed=3)
# Section 6: BENCH_MAP played by a cooperative team of 4 (TreasureHunt-v0 of it is agent 0 alone).
TEAM_AGENTS = 4
TEAM_MAP: dict[str, Any] = {**BENCH_MAP, "num_agents": TEAM_AGENTS, "mode": "cooperative"}


def replay_warmup(agent: AgentConfig) -> int:
    """Transitions in replay before an update is timed: ``learning_starts``, and enough for two batches."""
    return max(agent.learning_starts, 2 * agent.batch_size)


def rates(steps: int, wall: float, cpu: float) -> dict[str, float]:
    """``steps`` done in ``wall`` and ``cpu`` seconds, and the steps per second of each clock."""
    return {
        "steps": steps,
        "seconds": wall,
        "cpu_seconds": cpu,
        "steps_per_s": steps / wall,
        "steps_per_cpu_s": steps / cpu,
    }


def sb3_kwargs(agent: AgentConfig) -> dict[str, Any]:
    """SB3 ``DQN`` keywords matching ``agent`` (its exploration keys are the trainer's schedule)."""
    return {
        **{sb3: getattr(agent, ours) for ours, sb3 in SB3_NAMES.items()},
        "policy_kwargs": dict(net_arch=list(agent.hidden)),
        "device": "cpu",
    }


def sb3_dqn(agent: AgentConfig, env_kwargs: dict[str, Any], seed: int):
    """``stable_baselines3.DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0", **env_kwargs), ...)``."""
    from stable_baselines3 import DQN  # optional dependency: only the SB3 measurements need it

    env = gymnasium.make("TreasureHunt-v0", **env_kwargs)
    return DQN("MlpPolicy", env, seed=seed, verbose=0, **sb3_kwargs(agent))
