"""Section 2, DQN training steps/s on ``TreasureHunt-v0``: our trainer against Stable-Baselines3.

Ours is ``Trainer(plan_run(config, source_task=True), run_dir).run()``, what ``python train.py`` does on the
source task: the loop with its TensorBoard logging, progress bar off. Its greedy evaluations and
checkpoint writes (``summary["overhead"]``) are subtracted, since SB3's ``learn`` does neither. SB3 is
``DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0"), ...).learn(steps)``. Both get the hyperparameters
of one :class:`~dqn_transfer.config.AgentConfig` (``BENCH_AGENT``).

After training, both play the same greedy episodes through :func:`dqn_transfer.evaluation.rollout.play_episode`
on the numpy game ``TreasureHunt-v0`` wraps, so their success figures are comparable.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dqn_transfer.benchmark.config import BENCH_AGENT, SOURCE_MAP, rates, sb3_dqn
from dqn_transfer.config import AgentConfig, EnvConfig, TrainConfig
from dqn_transfer.envs import make_game
from dqn_transfer.evaluation.rollout import Policy, greedy_policy, play_episode
from dqn_transfer.timing import Stopwatch
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

# The greedy episodes are seeded apart from training's (the start is fixed, so a deterministic
# policy plays the same episode each time: a few suffice).
GREEDY_SEED_OFFSET = 10_000


def greedy_check(policy: Policy, env_kwargs: dict[str, Any], episodes: int, seed: int) -> dict[str, float]:
    """Greedy episodes on the single-agent game of ``env_kwargs``: the fraction that reach a full chest,
    and the mean return."""
    game = make_game(**env_kwargs).single_agent_game()
    results = [play_episode(game, policy, np.random.default_rng(seed + episode)) for episode in range(episodes)]
    return {
        "greedy_success": float(np.mean([r.treasures_collected > 0 for r in results])),
        "greedy_return": float(np.mean([r.team_return for r in results])),
    }


def _train_ours(steps: int, seed: int, agent: AgentConfig, env_kwargs: dict[str, Any]) -> tuple[dict, Policy]:
    """Our trainer on the source task, its evaluations and checkpoints subtracted."""
    config = TrainConfig(
        env=EnvConfig(**env_kwargs),
        agent=agent,
        seed=seed,
        total_steps=steps,
        eval_every=steps,  # at step 0 and at the end, one episode each: as little as the trainer allows
        eval_episodes=1,
        checkpoint_every=steps,
        progress=False,
        threads=torch.get_num_threads(),  # the trainer sets torch's (global) thread count from this
    )
    with tempfile.TemporaryDirectory(prefix="dqn_transfer_bench_") as tmp:
        trainer = Trainer(plan_run(config, source_task=True), Path(tmp) / "run")
        with Stopwatch() as run:
            summary = trainer.run()
    overhead = summary["overhead"]
    learner: Any = trainer.learner  # the DQN family's batched learner
    figures = {
        **rates(steps, run.wall - overhead["wall"], run.cpu - overhead["cpu"]),
        "gradient_steps": int(learner.num_gradient_steps),
        "run_seconds": run.wall,
        "excluded_seconds": overhead["wall"],
        "excluded_cpu_seconds": overhead["cpu"],
    }
    return figures, greedy_policy(learner)


def _train_sb3(steps: int, seed: int, agent: AgentConfig, env_kwargs: dict[str, Any]) -> tuple[dict, Policy]:
    """SB3's ``DQN.learn(steps)`` with the same hyperparameters."""
    model = sb3_dqn(agent, env_kwargs, seed)
    with Stopwatch() as run:
        model.learn(total_timesteps=steps, progress_bar=False)
    model.get_env().close()

    def policy(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        return np.array([int(model.predict(obs[0], deterministic=True)[0])])

    # SB3 keeps its gradient-step count only in _n_updates
    return {**rates(steps, run.wall, run.cpu), "gradient_steps": int(model._n_updates)}, policy


def measure_training(
    who: str,
    steps: int,
    seed: int,
    agent: AgentConfig = BENCH_AGENT,
    env_kwargs: dict[str, Any] = SOURCE_MAP,
    eval_episodes: int = 3,
) -> dict[str, Any]:
    """Env steps/s of ``who``'s training (``ours`` or ``sb3``), then its greedy episodes' figures."""
    figures, policy = (_train_ours if who == "ours" else _train_sb3)(steps, seed, agent, env_kwargs)
    return {**figures, **greedy_check(policy, env_kwargs, eval_episodes, seed + GREEDY_SEED_OFFSET)}
