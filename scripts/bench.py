"""Benchmarks of DESIGN section 7, measured side by side in one run on one machine.

    python scripts/bench.py [--quick] [--out outputs/bench.json] [--seed 0] [--repeats 3] [--threads 1]

1. Environment throughput: joint steps/s with random actions, through the PettingZoo
   ``ParallelEnv`` API and through the numpy core (``scripts/bench_env.py``), 1, 4 and 8 agents.
2. DQN training steps/s on ``TreasureHunt-v0``: our ``DQNLearner`` driven by the project's own
   ``Trainer`` (``source_task=True``, progress bar off) against Stable-Baselines3 ``DQN`` with matched
   hyperparameters.
3. Per-step cost as the team grows: the batched learner for K = 1, 2, 4, 8 agents against K separate
   single-agent ``DQNLearner`` instances stepped in a Python loop.
4. Time per gradient update (K = 1): ``DQNLearner``'s gradient step against a bare CleanRL-style
   PyTorch update on a pre-sampled batch (and SB3's ``DQN.train``); the bare and our update are also
   timed at torch's default thread count.

Threads. Every measurement runs at ``--threads`` torch threads (default 1: for networks this small,
intra-op parallelism costs more in synchronisation than it gains, and on a busy machine a second
thread that has to wait for a core can make an update tens of times slower). Section 4 shows the
default-thread figure beside it; the default-thread update timings stop after ``thread_cap_s``.

Method. The machine may be shared and noisy, so every figure is the median of ``--repeats``
interleaved repeats (the contenders of a comparison alternate within each repeat), and every ratio
is the median of the per-repeat paired ratios rather than a ratio of medians. Two clocks are read:
wall time (what a user waits) and process CPU time (what the work costs; much less disturbed by other
jobs, so on a shared machine the CPU ratios are the ones to trust). Setup (building networks, filling
replay before ``learning_starts``) is never timed. The table goes to stdout, progress to stderr, and
everything (with the raw per-repeat figures and the machine) to ``--out`` (written atomically).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))  # scripts/bench_env.py

from bench_env import BENCH_MAP, measure_env_throughput  # noqa: E402

import dqn_transfer  # noqa: E402,F401  (registers TreasureHunt-v0)

# Section 2's single-agent task: the same 10 x 10, complexity 0.1 map family as BENCH_MAP, but with one
# chest 6 moves from the start, so an episode is a real navigation problem (on BENCH_MAP's 4-chest
# map agent 0 starts next to a chest: every episode would last one step).
SOURCE_MAP = dict(size=10, num_treasures=1, num_traps=1, complexity=0.1, map_seed=2)

# Matched hyperparameters (our names; SB3's are derived in sb3_kwargs).
HP: dict[str, Any] = dict(
    lr=1e-3,
    gamma=0.99,
    batch_size=64,
    buffer_size=50_000,
    learning_starts=1_000,
    train_freq=1,
    gradient_steps=1,
    target_update=500,
    tau=1.0,
    hidden=[64, 64],
    max_grad_norm=10.0,
    eps_start=1.0,
    eps_end=0.05,
    exploration_fraction=0.5,
)
_TRAINER_ONLY = ("eps_start", "eps_end", "exploration_fraction")

PROFILES = {
    "full": dict(env_steps=20_000, train_steps=10_000, team_steps=400, updates=2_000, eval_episodes=5,
                 thread_cap_s=3.0),
    # quick: section 3 fills only 200 steps of replay before timing (the fill level hardly changes the
    # per-step cost) and section 4 skips the default-thread timings; the hyperparameters stay matched.
    "quick": dict(env_steps=2_000, train_steps=2_000, team_steps=40, updates=200, eval_episodes=2,
                  team_learning_starts=200, default_thread_timings=0),
}
DEFAULT_THREADS = torch.get_num_threads()  # torch's own choice on this machine, read before any change
ENV_AGENTS = (1, 4, 8)
TEAM_SIZES = (1, 2, 4, 8)


class Stopwatch:
    """Wall-clock and process CPU time of a ``with`` block (``.wall``, ``.cpu``, in seconds).

    Wall time is what a user waits; CPU time (all threads of this process) is what the work costs,
    and is far less disturbed by other jobs on a shared machine, so ratios are given in both.
    """

    def __enter__(self) -> "Stopwatch":
        self.wall, self.cpu = 0.0, 0.0
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self._wall0
        self.cpu = time.process_time() - self._cpu0


def learner_kwargs(hp: dict[str, Any]) -> dict[str, Any]:
    """The DQNLearner constructor keywords of ``hp`` (the exploration schedule belongs to the loop)."""
    return {key: value for key, value in hp.items() if key not in _TRAINER_ONLY}


def sb3_kwargs(hp: dict[str, Any]) -> dict[str, Any]:
    """SB3 ``DQN`` keywords matching ``hp``."""
    return dict(
        learning_rate=hp["lr"],
        gamma=hp["gamma"],
        batch_size=hp["batch_size"],
        buffer_size=hp["buffer_size"],
        learning_starts=hp["learning_starts"],
        train_freq=hp["train_freq"],
        gradient_steps=hp["gradient_steps"],
        target_update_interval=hp["target_update"],
        tau=hp["tau"],
        max_grad_norm=hp["max_grad_norm"],
        exploration_initial_eps=hp["eps_start"],
        exploration_final_eps=hp["eps_end"],
        exploration_fraction=hp["exploration_fraction"],
        policy_kwargs=dict(net_arch=list(hp["hidden"])),
        device="cpu",
    )


# ----------------------------------------------------------------------------- 1. environment
def measure_env(num_agents: int, steps: int, seed: int) -> dict[str, Any]:
    """Joint steps/s through PettingZoo and through the numpy core (see ``bench_env.py``)."""
    return measure_env_throughput(num_agents, steps, seed)


# ----------------------------------------------------------------------------- 2. training
def greedy_success(policy: Callable[[np.ndarray], int], env_kwargs: dict, episodes: int, seed: int) -> dict:
    """Greedy episodes on ``TreasureHunt-v0``: fraction that reach a full chest, and mean return.

    One procedure for both learners, so their figures are comparable (the start is fixed, so a
    deterministic policy plays the same episode each time; a few episodes suffice).
    """
    import gymnasium

    env = gymnasium.make("TreasureHunt-v0", **env_kwargs)
    found, returns = [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        done, total, got = False, 0.0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            total += reward
            got = got or info["treasures_collected"] > 0
            done = terminated or truncated
        found.append(got)
        returns.append(total)
    env.close()
    return {"greedy_success": float(np.mean(found)), "greedy_return": float(np.mean(returns))}


def measure_ours_training(
    steps: int,
    seed: int,
    hp: dict[str, Any] = HP,
    env_kwargs: dict[str, Any] = SOURCE_MAP,
    eval_episodes: int = 3,
) -> dict[str, Any]:
    """Env steps/s of ``Trainer(config, run_dir, source_task=True).run()`` on ``TreasureHunt-v0``.

    This is what ``python train.py`` does on the source task: the loop with its TensorBoard logging.
    Its two greedy evaluations (step 0 and the end, one episode each) and its checkpoint writes are
    timed and subtracted, since SB3's ``learn`` does neither. ``greedy_success`` comes from the same
    post-training procedure as SB3's (``greedy_success``), not from the trainer's evaluations.
    """
    from dqn_transfer.config import AgentConfig, Algorithm, EnvConfig, TrainConfig
    from dqn_transfer.train import Trainer

    config = TrainConfig(
        env=EnvConfig(**env_kwargs),
        agent=AgentConfig(algorithm=Algorithm.dqn, **hp),
        seed=seed,
        total_steps=steps,
        eval_every=steps,
        eval_episodes=1,
        checkpoint_every=steps,
        progress=False,
        threads=torch.get_num_threads(),  # the Trainer sets torch's (global) thread count from this
    )
    excluded = {"wall": 0.0, "cpu": 0.0}

    def timed(method):
        def wrapper(*args, **kwargs):
            with Stopwatch() as watch:
                result = method(*args, **kwargs)
            excluded["wall"] += watch.wall
            excluded["cpu"] += watch.cpu
            return result

        return wrapper

    with tempfile.TemporaryDirectory(prefix="dqn_transfer_bench_") as tmp:
        trainer = Trainer(config, Path(tmp) / "run", source_task=True, launch_dir=Path(tmp))
        trainer.run_evaluation = timed(trainer.run_evaluation)  # type: ignore[method-assign]
        trainer.save_checkpoint = timed(trainer.save_checkpoint)  # type: ignore[method-assign]
        with Stopwatch() as watch:
            trainer.run()
    seconds, cpu_seconds = watch.wall - excluded["wall"], watch.cpu - excluded["cpu"]
    learner = trainer.learner
    live = np.ones(1, dtype=bool)

    def policy(obs: np.ndarray) -> int:
        return int(learner.act(obs[None], live, epsilon=0.0, greedy=True)[0])

    return {
        "steps": steps,
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
        "excluded_seconds": excluded["wall"],
        "steps_per_s": steps / seconds,
        "steps_per_cpu_s": steps / cpu_seconds,
        "gradient_steps": int(learner.num_gradient_steps),
        **greedy_success(policy, env_kwargs, eval_episodes, seed + 10_000),
    }


def measure_sb3_training(
    steps: int,
    seed: int,
    hp: dict[str, Any] = HP,
    env_kwargs: dict[str, Any] = SOURCE_MAP,
    eval_episodes: int = 3,
) -> dict[str, Any]:
    """Env steps/s of ``stable_baselines3.DQN("MlpPolicy", env, ...).learn(steps)``, same hyperparameters."""
    import gymnasium
    from stable_baselines3 import DQN

    env = gymnasium.make("TreasureHunt-v0", **env_kwargs)
    model = DQN("MlpPolicy", env, seed=seed, verbose=0, **sb3_kwargs(hp))
    with Stopwatch() as watch:
        model.learn(total_timesteps=steps, progress_bar=False)
    env.close()

    def policy(obs: np.ndarray) -> int:
        return int(model.predict(obs, deterministic=True)[0])

    return {
        "steps": steps,
        "seconds": watch.wall,
        "cpu_seconds": watch.cpu,
        "steps_per_s": steps / watch.wall,
        "steps_per_cpu_s": steps / watch.cpu,
        "gradient_steps": int(model._n_updates),
        **greedy_success(policy, env_kwargs, eval_episodes, seed + 10_000),
    }


# ----------------------------------------------------------------------------- 3. team size
class TeamRig:
    """K agents on a 10 x 10 map, driven like the trainer drives them: act, step, update.

    ``separate=False``: one batched ``DQNLearner`` for the K agents (the project's learner);
    ``separate=True``: K single-agent ``DQNLearner`` instances, one after another in a Python loop.
    The map is ``BENCH_MAP`` generated for K starts (as in section 1). Construction plays
    ``learning_starts`` random steps (replay filling, no gradient), so every timed step trains.
    """

    def __init__(self, num_agents: int, separate: bool, seed: int, hp: dict[str, Any] = HP):
        from dqn_transfer.agents import DQNLearner
        from dqn_transfer.envs import make_game

        self.num_agents, self.separate, self.hp = num_agents, separate, hp
        self.game = make_game(**BENCH_MAP, num_agents=num_agents)
        layout, actions = self.game.obs_layout(), self.game.num_actions
        kwargs = learner_kwargs(hp)
        if separate:
            self.learners = [DQNLearner(1, layout, actions, seed=seed + i, **kwargs) for i in range(num_agents)]
        else:
            self.learners = [DQNLearner(num_agents, layout, actions, seed=seed, **kwargs)]
        self.rng = np.random.default_rng(seed)
        self.obs = self.game.reset(self.rng)
        self.step_count = 0
        for _ in range(hp["learning_starts"]):
            self._step(hp["eps_start"])

    def _step(self, epsilon: float) -> None:
        game, obs = self.game, self.obs
        live = game.live
        if self.separate:
            actions = np.concatenate(
                [learner.act(obs[i : i + 1], live[i : i + 1], epsilon) for i, learner in enumerate(self.learners)]
            )
        else:
            actions = self.learners[0].act(obs, live, epsilon)
        next_obs, rewards, terminated, truncated, _ = game.step(actions)
        self.step_count += 1
        if self.separate:
            for i, learner in enumerate(self.learners):
                s = slice(i, i + 1)
                learner.update(obs[s], actions[s], rewards[s], next_obs[s], terminated[s], truncated[s],
                               live[s], self.step_count)
        else:
            self.learners[0].update(obs, actions, rewards, next_obs, terminated, truncated, live, self.step_count)
        self.obs = game.reset(self.rng) if game.done else next_obs

    def run(self, steps: int) -> Stopwatch:
        """Time ``steps`` joint env steps, each with its gradient update (epsilon = eps_end)."""
        epsilon = self.hp["eps_end"]
        with Stopwatch() as watch:
            for _ in range(steps):
                self._step(epsilon)
        return watch


def measure_team_step_cost(num_agents: int, steps: int, seed: int, separate: bool = False,
                           hp: dict[str, Any] = HP) -> dict[str, Any]:
    """ms per joint env step (act + env step + store + gradient update) and per agent-step."""
    watch = TeamRig(num_agents, separate, seed, hp).run(steps)
    ms = 1000.0 * watch.wall / steps
    return {"num_agents": num_agents, "separate": separate, "steps": steps, "ms_per_step": ms,
            "ms_per_agent_step": ms / num_agents, "cpu_ms_per_step": 1000.0 * watch.cpu / steps}


# ----------------------------------------------------------------------------- 4. gradient update
class UpdateRig:
    """One gradient update four ways, on the single-agent task's shapes (obs 100, 4 actions, batch 64).

    - ``bare``: CleanRL-style update of an ``nn.Sequential`` (Linear/ReLU) on a batch already in
      memory as tensors: target max under no_grad, gather, Huber loss, backward,
      ``clip_grad_norm_``, Adam step. The floor PyTorch gives for this work.
    - ``bare_batched``: the same on our ``BatchedMLP`` (K = 1) with our per-member clip, batch in memory.
    - ``ours``: ``DQNLearner._gradient_step()``: replay sample + the above + per-agent loss/Q statistics.
    - ``sample``: ``ReplayBuffer.sample`` alone (part of ``ours``).
    """

    def __init__(self, seed: int, hp: dict[str, Any] = HP, env_kwargs: dict[str, Any] = SOURCE_MAP):
        from dqn_transfer.agents import BatchedMLP, DQNLearner
        from dqn_transfer.envs import make_game

        game = make_game(**env_kwargs).single_agent_game()
        self.learner = DQNLearner(1, game.obs_layout(), game.num_actions, seed=seed, **learner_kwargs(hp))
        rng = np.random.default_rng(seed)
        obs, live = game.reset(rng), np.ones(1, dtype=bool)
        for _ in range(max(hp["learning_starts"], 2 * hp["batch_size"])):  # real transitions, random play
            actions = rng.integers(0, game.num_actions, size=1)
            next_obs, rewards, terminated, truncated, _ = game.step(actions)
            self.learner.replay.add(obs, actions, rewards, next_obs, terminated, truncated, mask=live)
            obs = game.reset(rng) if game.done else next_obs
        self.gamma, self.max_grad_norm = hp["gamma"], hp["max_grad_norm"]
        self.batch = self.learner.replay.sample(hp["batch_size"])  # [1, B, ...]
        self.flat_batch = {name: t[0] for name, t in self.batch.items() if name != "valid"}  # [B, ...]

        torch.manual_seed(seed)
        sizes = [game.obs_dim, *hp["hidden"], game.num_actions]
        layers: list[nn.Module] = []
        for i, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:])):
            layers.append(nn.Linear(fan_in, fan_out))
            if i < len(sizes) - 2:
                layers.append(nn.ReLU())
        self.q = nn.Sequential(*layers)
        self.q_target = copy.deepcopy(self.q).requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.q.parameters(), lr=hp["lr"])

        self.bq = BatchedMLP(1, game.obs_dim, hp["hidden"], game.num_actions, torch.Generator().manual_seed(seed))
        self.bq_target = copy.deepcopy(self.bq).requires_grad_(False)
        self.b_optimizer = torch.optim.Adam(self.bq.parameters(), lr=hp["lr"])

    def _bare_update(self) -> None:
        b = self.flat_batch
        with torch.no_grad():
            target_max = self.q_target(b["next_obs"]).max(dim=1).values
            td_target = b["rewards"] + self.gamma * target_max * (1.0 - b["terminated"].float())
        q_taken = self.q(b["obs"]).gather(1, b["actions"].unsqueeze(1)).squeeze(1)
        loss = F.smooth_l1_loss(q_taken, td_target)
        self.optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.q.parameters(), self.max_grad_norm)
        self.optimizer.step()

    def _bare_batched_update(self) -> None:
        b = self.batch
        with torch.no_grad():
            target_max = self.bq_target(b["next_obs"]).max(dim=-1).values
            td_target = b["rewards"] + self.gamma * target_max * (1.0 - b["terminated"].float())
        q_taken = self.bq(b["obs"]).gather(-1, b["actions"].unsqueeze(-1)).squeeze(-1)
        loss = F.smooth_l1_loss(q_taken, td_target, reduction="none").mean(dim=1).sum()
        self.b_optimizer.zero_grad()
        loss.backward()
        self.bq.clip_grad_norm_(self.max_grad_norm)
        self.b_optimizer.step()

    def time(self, which: str, updates: int, max_seconds: float | None = None) -> tuple[float, float]:
        """(wall, CPU) microseconds per update of ``which`` in (bare, bare_batched, ours, sample): the
        mean over ``updates`` calls, or over those done within ``max_seconds`` if that comes first."""
        fn = {
            "bare": self._bare_update,
            "bare_batched": self._bare_batched_update,
            "ours": self.learner._gradient_step,
            "sample": lambda: self.learner.replay.sample(self.learner.batch_size),
        }[which]
        fn()  # warm-up (first-call allocations)
        deadline = math.inf if max_seconds is None else time.perf_counter() + max_seconds
        done = 0
        with Stopwatch() as watch:
            while done < updates:
                fn()
                done += 1
                if time.perf_counter() > deadline:
                    break
        return 1e6 * watch.wall / done, 1e6 * watch.cpu / done


class SB3UpdateRig:
    """SB3 ``DQN.train`` per gradient step (replay sample included), replay filled by ``learn``."""

    def __init__(self, seed: int, hp: dict[str, Any] = HP, env_kwargs: dict[str, Any] = SOURCE_MAP):
        import gymnasium
        from stable_baselines3 import DQN

        self.env = gymnasium.make("TreasureHunt-v0", **env_kwargs)
        self.model = DQN("MlpPolicy", self.env, seed=seed, verbose=0, **sb3_kwargs(hp))
        self.model.learn(total_timesteps=max(hp["learning_starts"], 2 * hp["batch_size"]))  # no training yet
        self.batch_size = hp["batch_size"]

    def time(self, updates: int) -> tuple[float, float]:
        """(wall, CPU) microseconds per gradient step."""
        self.model.train(gradient_steps=1, batch_size=self.batch_size)
        with Stopwatch() as watch:
            self.model.train(gradient_steps=updates, batch_size=self.batch_size)
        return 1e6 * watch.wall / updates, 1e6 * watch.cpu / updates


UPDATE_NAMES = ("bare", "bare_batched", "ours", "sample", "sb3")
THREAD_NAMES = ("bare", "ours")  # also timed at torch's default thread count


def measure_update_cost(updates: int, seed: int, hp: dict[str, Any] = HP, with_sb3: bool = True) -> dict[str, float]:
    """Wall-clock microseconds per gradient update (one pass of each variant; see ``UpdateRig``)."""
    rig = UpdateRig(seed, hp)
    result = {name: rig.time(name, updates)[0] for name in ("bare", "bare_batched", "ours", "sample")}
    if with_sb3:
        result["sb3"] = SB3UpdateRig(seed, hp).time(updates)[0]
    return result


# ----------------------------------------------------------------------------- driver
class Progress:
    """``[  3/40  12.1s] what`` lines on stderr."""

    def __init__(self, total: int):
        self.total, self.done, self.start = total, 0, time.perf_counter()

    def __call__(self, what: str) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.start
        print(f"[{self.done:>3}/{self.total} {elapsed:6.1f}s] {what}", file=sys.stderr, flush=True)


def median(values) -> float:
    return float(statistics.median(values))


def paired_ratio(a: list[float], b: list[float]) -> float:
    """Median over repeats of ``a[r] / b[r]``: each pair was measured back to back."""
    return median(x / y for x, y in zip(a, b))


def machine_info(threads_used: list[int]) -> dict[str, Any]:
    import gymnasium
    import pettingzoo
    import stable_baselines3

    cpu_model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu_model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "cpu_model": cpu_model,
        "cpu_count": os.cpu_count(),
        "cpus_available": affinity,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "gymnasium": gymnasium.__version__,
        "pettingzoo": pettingzoo.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch_default_threads": DEFAULT_THREADS,
        "torch_threads_used": threads_used,
    }



def run_benchmark(profile: str, seed: int, repeats: int, threads: int, train_threads: list[int],
                  sizes: dict[str, int] | None = None, hp: dict[str, Any] = HP) -> dict[str, Any]:
    """All four measurements; ``sizes`` defaults to ``PROFILES[profile]``. Returns the JSON document."""
    sizes = dict(PROFILES[profile] if sizes is None else sizes)
    team_hp = {**hp, "learning_starts": sizes.get("team_learning_starts", hp["learning_starts"])}
    with_default_threads = bool(sizes.get("default_thread_timings", 1)) and DEFAULT_THREADS != threads
    thread_variants = len(THREAD_NAMES) if with_default_threads else 0
    total = (repeats * len(ENV_AGENTS) + repeats * len(train_threads) * 2 + 2 * len(TEAM_SIZES)
             + repeats * len(TEAM_SIZES) * 2 + 2 + repeats * (len(UPDATE_NAMES) + thread_variants))
    progress = Progress(total)
    results: dict[str, Any] = {"loadavg_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}

    # 1. environment ------------------------------------------------------------------------
    torch.set_num_threads(threads)
    env_raw = {k: [] for k in ENV_AGENTS}
    for r in range(repeats):
        for k in ENV_AGENTS:
            env_raw[k].append(measure_env(k, sizes["env_steps"], seed + r))
            progress(f"env throughput, {k} agent(s), repeat {r + 1}/{repeats}")
    results["env"] = [
        {
            "num_agents": k,
            "steps": sizes["env_steps"],
            "pettingzoo_steps_per_s": median(x["joint_steps_per_s"] for x in env_raw[k]),
            "core_steps_per_s": median(x["core_steps_per_s"] for x in env_raw[k]),
            "core_over_pettingzoo": median(x["core_steps_per_s"] / x["joint_steps_per_s"] for x in env_raw[k]),
            "raw": env_raw[k],
        }
        for k in ENV_AGENTS
    ]

    # 2. training ---------------------------------------------------------------------------
    train_raw: dict[int, dict[str, list]] = {t: {"ours": [], "sb3": []} for t in train_threads}
    for r in range(repeats):
        for t in train_threads:
            order = ("ours", "sb3") if r % 2 == 0 else ("sb3", "ours")
            for who in order:
                torch.set_num_threads(t)
                measure = measure_ours_training if who == "ours" else measure_sb3_training
                out = measure(sizes["train_steps"], seed + r, hp, eval_episodes=sizes["eval_episodes"])
                train_raw[t][who].append(out)
                progress(f"training {sizes['train_steps']} steps, {'ours' if who == 'ours' else 'SB3 DQN'}, "
                         f"{t} thread(s), repeat {r + 1}/{repeats}: {out['steps_per_s']:.0f} steps/s")
    results["training"] = []
    for t in train_threads:
        ours, sb3 = train_raw[t]["ours"], train_raw[t]["sb3"]
        results["training"].append({
            "torch_threads": t,
            "steps": sizes["train_steps"],
            "ours_steps_per_s": median(x["steps_per_s"] for x in ours),
            "sb3_steps_per_s": median(x["steps_per_s"] for x in sb3),
            "ours_over_sb3": paired_ratio([x["steps_per_s"] for x in ours], [x["steps_per_s"] for x in sb3]),
            "ours_steps_per_cpu_s": median(x["steps_per_cpu_s"] for x in ours),
            "sb3_steps_per_cpu_s": median(x["steps_per_cpu_s"] for x in sb3),
            "ours_over_sb3_cpu": paired_ratio([x["steps_per_cpu_s"] for x in ours],
                                              [x["steps_per_cpu_s"] for x in sb3]),
            "ours_greedy_success": float(np.mean([x["greedy_success"] for x in ours])),
            "sb3_greedy_success": float(np.mean([x["greedy_success"] for x in sb3])),
            "ours_greedy_return": float(np.mean([x["greedy_return"] for x in ours])),
            "sb3_greedy_return": float(np.mean([x["greedy_return"] for x in sb3])),
            "raw": {"ours": ours, "sb3": sb3},
        })

    # 3. team size --------------------------------------------------------------------------
    torch.set_num_threads(threads)
    rigs = {}
    for k in TEAM_SIZES:
        for separate in (False, True):
            rigs[k, separate] = TeamRig(k, separate, seed, team_hp)
            progress(f"team K={k}: {'separate learners' if separate else 'batched learner'} built, replay filled")
    team_raw: dict[tuple[int, bool], list[float]] = {key: [] for key in rigs}  # wall ms per step
    team_cpu: dict[tuple[int, bool], list[float]] = {key: [] for key in rigs}  # CPU ms per step
    for r in range(repeats):
        for k in TEAM_SIZES:
            order = (False, True) if r % 2 == 0 else (True, False)
            for separate in order:
                watch = rigs[k, separate].run(sizes["team_steps"])
                team_raw[k, separate].append(1000.0 * watch.wall / sizes["team_steps"])
                team_cpu[k, separate].append(1000.0 * watch.cpu / sizes["team_steps"])
                progress(f"team K={k}, {'separate' if separate else 'batched'}, repeat {r + 1}/{repeats}: "
                         f"{team_raw[k, separate][-1]:.2f} ms/step")
    del rigs
    results["team"] = [
        {
            "num_agents": k,
            "steps": sizes["team_steps"],
            "batched_ms_per_step": median(team_raw[k, False]),
            "batched_ms_per_agent_step": median(team_raw[k, False]) / k,
            "separate_ms_per_step": median(team_raw[k, True]),
            "separate_ms_per_agent_step": median(team_raw[k, True]) / k,
            "separate_over_batched": paired_ratio(team_raw[k, True], team_raw[k, False]),
            "batched_over_k1": median(team_raw[k, False]) / median(team_raw[1, False]),
            "batched_cpu_ms_per_step": median(team_cpu[k, False]),
            "separate_cpu_ms_per_step": median(team_cpu[k, True]),
            "separate_over_batched_cpu": paired_ratio(team_cpu[k, True], team_cpu[k, False]),
            "batched_over_k1_cpu": median(team_cpu[k, False]) / median(team_cpu[1, False]),
            "raw_ms": {"batched": team_raw[k, False], "separate": team_raw[k, True]},
            "raw_cpu_ms": {"batched": team_cpu[k, False], "separate": team_cpu[k, True]},
        }
        for k in TEAM_SIZES
    ]

    # 4. gradient update --------------------------------------------------------------------
    rig = UpdateRig(seed, hp)
    progress("update rig built (DQNLearner K=1, bare nn.Sequential, bare BatchedMLP)")
    sb3_rig = SB3UpdateRig(seed, hp)
    progress("SB3 update rig built (replay filled)")
    # (name, torch threads): everything at `threads`, plus bare and ours at torch's default thread
    # count (time-capped: on an oversubscribed machine multi-threaded tiny updates can crawl).
    def _variant_key(name: str, t: int) -> str:
        return name if t == threads else f"{name}_default_threads"

    variants = [(name, threads) for name in UPDATE_NAMES]
    variants += [(name, DEFAULT_THREADS) for name in THREAD_NAMES if with_default_threads]
    update_raw: dict[str, list[float]] = {_variant_key(*v): [] for v in variants}  # wall us
    update_cpu: dict[str, list[float]] = {_variant_key(*v): [] for v in variants}  # CPU us
    for r in range(repeats):
        for name, t in variants if r % 2 == 0 else variants[::-1]:
            torch.set_num_threads(t)
            cap = None if t == threads else sizes.get("thread_cap_s", 1.0)
            wall, cpu = sb3_rig.time(sizes["updates"]) if name == "sb3" else rig.time(name, sizes["updates"], cap)
            update_raw[_variant_key(name, t)].append(wall)
            update_cpu[_variant_key(name, t)].append(cpu)
            progress(f"gradient update: {name}, {t} thread(s), repeat {r + 1}/{repeats}: {wall:.0f} us")
    torch.set_num_threads(threads)
    results["update"] = {
        "updates": sizes["updates"],
        "threads": threads,
        "default_threads": DEFAULT_THREADS,
        **{f"{key}_us": median(raw) for key, raw in update_raw.items()},
        **{f"{key}_cpu_us": median(raw) for key, raw in update_cpu.items()},
        **{f"{key}_over_bare": paired_ratio(raw, update_raw["bare"]) for key, raw in update_raw.items()},
        **{f"{key}_over_bare_cpu": paired_ratio(raw, update_cpu["bare"]) for key, raw in update_cpu.items()},
        "raw_us": update_raw,
        "raw_cpu_us": update_cpu,
    }

    results["machine"] = machine_info(sorted({threads, *train_threads}))
    results["machine"]["loadavg_start"] = results.pop("loadavg_start")
    results["machine"]["loadavg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    results["settings"] = {
        "profile": profile, "seed": seed, "repeats": repeats, "threads": threads,
        "train_threads": train_threads, **sizes, "hyperparameters": hp,
        "team_learning_starts": team_hp["learning_starts"],
        "env_map": BENCH_MAP, "source_map": SOURCE_MAP,
    }
    results["method"] = METHOD
    return results


METHOD = (
    "Each figure is the median of R interleaved repeats (the contenders of a comparison alternate "
    "order inside each repeat); each ratio is the median of the per-repeat paired ratios. Setup "
    "(networks, replay filling before learning_starts) is untimed. Two clocks: wall (time.perf_counter, "
    "what a user waits) and CPU (time.process_time, all threads of the process: what the work costs, "
    "much less disturbed by other jobs on a shared machine). Compare ratios, not absolute figures, "
    "across machines."
)


def _fmt(x: float, digits: int = 0) -> str:
    return f"{x:,.{digits}f}"


def render_markdown(res: dict[str, Any]) -> str:
    s, m = res["settings"], res["machine"]
    hp = s["hyperparameters"]
    load = (f"; load average (1 min) at start {m['loadavg_start'][0]:.2f}, at end {m['loadavg_end'][0]:.2f}"
            if m.get("loadavg_start") else "")
    lines = [
        f"# dqn_transfer benchmark ({s['profile']})",
        "",
        f"Method: {res['method']} R = {s['repeats']}, seed {s['seed']}, torch threads {s['threads']} "
        "unless stated.",
        "",
        f"Machine: {m['cpu_model']}, {m['cpus_available']} CPU(s) available ({m['cpu_count']} total), "
        f"torch {m['torch']} (default {m['torch_default_threads']} threads), SB3 {m['stable_baselines3']}, "
        f"gymnasium {m['gymnasium']}, PettingZoo {m['pettingzoo']}, Python {m['python']}{load}.",
        "",
        f"## 1. Environment throughput (random actions, {s['env_steps']:,} joint steps, resets included)",
        "",
        f"Map: {s['env_map']} generated for K starts. Wall clock.",
        "",
        "| agents | PettingZoo ParallelEnv steps/s | numpy core steps/s | core / PettingZoo |",
        "|---:|---:|---:|---:|",
    ]
    for row in res["env"]:
        lines.append(f"| {row['num_agents']} | {_fmt(row['pettingzoo_steps_per_s'])} | "
                     f"{_fmt(row['core_steps_per_s'])} | {row['core_over_pettingzoo']:.2f}x |")
    lines += [
        "",
        f"## 2. DQN training on TreasureHunt-v0 ({s['train_steps']:,} env steps, "
        f"{max(0, s['train_steps'] - hp['learning_starts']):,} gradient steps)",
        "",
        f"Map: {s['source_map']} (one chest, 6 moves from the start). Ours: `Trainer(source_task=True).run()` "
        "(the training loop with its TensorBoard logging; progress bar off; its greedy evaluations and "
        "checkpoint writes timed and subtracted). SB3: `DQN(\"MlpPolicy\", gymnasium.make(\"TreasureHunt-v0\"), "
        f"...).learn()`. Matched: net_arch {hp['hidden']}, lr {hp['lr']}, batch {hp['batch_size']}, buffer "
        f"{hp['buffer_size']:,}, learning_starts {hp['learning_starts']}, train_freq {hp['train_freq']}, "
        f"gradient_steps {hp['gradient_steps']}, target_update {hp['target_update']}, gamma {hp['gamma']}, "
        f"epsilon {hp['eps_start']} -> {hp['eps_end']} over {hp['exploration_fraction']} of the run, "
        f"max_grad_norm {hp['max_grad_norm']}, Huber loss, Adam, CPU. Greedy success: fraction of greedy "
        "episodes reaching the chest after training (same procedure for both), mean over repeats.",
        "",
        "| torch threads | ours steps/s | SB3 steps/s | ours / SB3 (wall) | ours / SB3 (CPU) | "
        "ours greedy success | SB3 greedy success |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in res["training"]:
        lines.append(f"| {row['torch_threads']} | {_fmt(row['ours_steps_per_s'])} | {_fmt(row['sb3_steps_per_s'])} | "
                     f"{row['ours_over_sb3']:.2f}x | {row['ours_over_sb3_cpu']:.2f}x | "
                     f"{row['ours_greedy_success']:.2f} | {row['sb3_greedy_success']:.2f} |")
    lines += [
        "",
        f"## 3. Per-step cost as the team grows ({s['team_steps']} timed joint steps, every one with a gradient update)",
        "",
        f"ms per joint env step = act + env step + replay store + gradient update (batch {hp['batch_size']} "
        f"per agent), wall clock, after {s['team_learning_starts']} untimed replay-filling steps; map "
        f"{s['env_map']} generated for K starts, same hyperparameters. Batched: one DQNLearner for the K "
        "agents (stacked weights, one Adam step). Separate: K single-agent DQNLearners stepped in a Python loop.",
        "",
        "| K | batched ms/step | batched ms/agent-step | batched vs K=1 | separate ms/step | "
        "separate ms/agent-step | separate / batched (wall) | separate / batched (CPU) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in res["team"]:
        lines.append(f"| {row['num_agents']} | {row['batched_ms_per_step']:.2f} | {row['batched_ms_per_agent_step']:.2f} | "
                     f"{row['batched_over_k1']:.2f}x | {row['separate_ms_per_step']:.2f} | "
                     f"{row['separate_ms_per_agent_step']:.2f} | {row['separate_over_batched']:.2f}x | "
                     f"{row['separate_over_batched_cpu']:.2f}x |")
    u = res["update"]
    lines += [
        "",
        f"## 4. Time per gradient update (K = 1, obs 100, batch {hp['batch_size']}, {u['updates']:,} updates per timing)",
        "",
        "Bare = CleanRL-style update of an nn.Sequential on a batch already in memory as tensors (target "
        "max under no_grad, gather, Huber loss, backward, clip_grad_norm_, Adam step).",
        "",
        "| update | wall us/update | CPU us/update | vs bare (wall) | vs bare (CPU) |",
        "|---|---:|---:|---:|---:|",
    ]
    rows = [
        ("bare", "bare PyTorch, nn.Sequential, pre-sampled batch"),
        ("bare_batched", "bare PyTorch, our BatchedMLP (K=1) + per-member clip, pre-sampled batch"),
        ("ours", "DQNLearner._gradient_step (replay sample + update + per-agent loss/Q stats)"),
        ("sample", "of which ReplayBuffer.sample"),
        ("sb3", "SB3 DQN.train, per gradient step (replay sample included)"),
        ("bare_default_threads", f"bare PyTorch, nn.Sequential, {u['default_threads']} threads (torch default)"),
        ("ours_default_threads", f"DQNLearner._gradient_step, {u['default_threads']} threads (torch default)"),
    ]
    for key, label in rows:
        if f"{key}_us" in u:
            lines.append(f"| {label} | {u[key + '_us']:.0f} | {u[key + '_cpu_us']:.0f} | "
                         f"{u[key + '_over_bare']:.2f}x | {u[key + '_over_bare_cpu']:.2f}x |")
    lines.append("")
    return "\n".join(lines)


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Benchmark table of DESIGN section 7 (env, training vs SB3, team size, update overhead).")
    parser.add_argument("--quick", action="store_true",
                        help="small sizes: a smoke run (< 1 min)")
    parser.add_argument("--out", type=Path, default=Path("outputs/bench.json"), help="JSON output path")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=positive_int, default=3,
                        help="interleaved repeats per measurement; the median is reported (default 3)")
    parser.add_argument("--threads", type=positive_int, default=1,
                        help="torch threads for every measurement (default 1, fastest for these tiny "
                             "networks); section 4 also times torch's default thread count")
    args = parser.parse_args(argv)
    if args.out.exists() and args.out.is_dir():
        parser.error(f"--out {args.out} is a directory; give a file path such as {args.out / 'bench.json'}")
    return args


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Atomic write: a temp file beside the target, then ``os.replace``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
    os.replace(tmp, path)


def check_ready(out: Path) -> None:
    """Fail in the first second, not after minutes of measuring: SB3 present, --out writable."""
    import importlib.util

    if importlib.util.find_spec("stable_baselines3") is None:
        sys.exit("error: scripts/bench.py compares against Stable-Baselines3: pip install -e '.[dev]'")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        sys.exit(f"error: cannot create {out.parent}: {err.strerror}")
    try:  # a real write: os.access says yes to root even where writing fails (e.g. /proc)
        with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".probe"):
            pass
    except OSError as err:
        sys.exit(f"error: cannot write into {out.parent}: {err.strerror}")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    check_ready(Path(args.out))
    profile = "quick" if args.quick else "full"
    start = time.perf_counter()
    results = run_benchmark(profile, args.seed, args.repeats, args.threads, [args.threads])
    results["total_seconds"] = time.perf_counter() - start
    table = render_markdown(results)
    results["markdown"] = table
    print(table)
    write_json(args.out, results)
    print(f"wrote {args.out} ({results['total_seconds']:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
