"""The driver: the six measurements, interleaved repeats, paired ratios, the Markdown table, the JSON document.

Threads. Sections 1-4 run at ``threads`` torch threads (the CLI's default is 1: for networks this
small, intra-op parallelism costs more in synchronisation than it gains, and on a busy machine a second
thread that has to wait for a core can make an update tens of times slower). Section 4 shows the
default-thread figure beside it; the default-thread update timings stop after ``thread_cap_s``. Section
5's processes run on one thread each; in section 6 SB3 gets every core (one single-threaded process
per core) and ours one process on one thread: both engines, whose second torch thread measured slower
here (spin-waiting for a core that SB3's processes, or any other job, hold).

Method. The machine may be shared and noisy, so every figure is the median of ``repeats`` interleaved
repeats (the contenders of a comparison alternate order within each repeat), and every ratio is the
median of the per-repeat paired ratios rather than a ratio of medians. Two clocks are read: wall time
(what a user waits) and process CPU time (what the work costs; much less disturbed by other jobs, so on
a shared machine the CPU ratios are the ones to trust). Setup (building networks, filling replay before
``learning_starts``) is never timed in sections 1-4. Sections 5 and 6 time whole processes instead
(spawn to exit, setup included: :mod:`~dqn_transfer.benchmark.whole_process`); they record the load
average at their own start and end, since a process-level figure is the most exposed to other jobs.
:func:`run_benchmark` returns everything, with the raw per-repeat figures and the machine, as one
JSON-able document; :func:`render_markdown` makes the table of it.
"""

from __future__ import annotations

import dataclasses
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numpy as np
import torch

from dqn_transfer.benchmark.config import BENCH_AGENT, BENCH_MAP, LONE_AGENT, LONE_MAP, SOURCE_MAP, TEAM_MAP
from dqn_transfer.benchmark.env_throughput import measure_env_throughput
from dqn_transfer.benchmark.team_scaling import TeamRig
from dqn_transfer.benchmark.training import measure_ours_training, measure_sb3_training
from dqn_transfer.benchmark.update_cost import THREAD_NAMES, UPDATE_NAMES, SB3UpdateRig, UpdateRig
from dqn_transfer.benchmark.whole_process import (
    LONE_CONTENDERS,
    measure_lone,
    measure_ours_replicas,
    measure_sb3_parallel,
)
from dqn_transfer.config import AgentConfig, to_plain
from dqn_transfer.enums import Engine
from dqn_transfer.timing import cpu_model, cpus_available

SECTIONS = ("env", "training", "team", "update", "lone", "replicas")
NEEDS_SB3 = ("training", "update", "lone", "replicas")
ENV_AGENTS = (1, 4, 8)
TEAM_SIZES = (1, 2, 4, 8)
DEFAULT_THREADS = torch.get_num_threads()  # torch's own choice on this machine, read before any change


@dataclass(frozen=True)
class Sizes:
    """How much each measurement does per repeat."""

    env_steps: int  # section 1: joint steps per path
    train_steps: int  # section 2: env steps per training run
    team_steps: int  # section 3: timed joint steps per rig
    updates: int  # section 4: gradient updates per timing
    eval_episodes: int  # section 2: greedy episodes after training
    thread_cap_s: float = 1.0  # section 4: time limit of a default-thread timing
    team_learning_starts: int | None = None  # section 3: replay filled before timing (None: the agent's)
    default_thread_timings: bool = True  # section 4: also time bare and ours at torch's default threads
    lone_steps: int = 10_000  # section 5: env steps per process
    replica_steps: int = 3_000  # section 6: joint env steps per process
    replica_counts: tuple[int, ...] = (1, 4, 10, 16, 64)  # section 6: replicas.seeds of our processes
    replica_learning_starts: int = 500  # section 6: env steps before the first update, ours and SB3's


PROFILES = {
    "full": Sizes(
        env_steps=20_000,
        train_steps=10_000,
        team_steps=400,
        updates=2_000,
        eval_episodes=5,
        thread_cap_s=3.0,
        lone_steps=10_000,
        replica_steps=3_000,
        replica_counts=(1, 4, 10, 16, 64),
        replica_learning_starts=500,
    ),
    # quick: section 3 fills only 200 steps of replay before timing (the fill level hardly changes the
    # per-step cost) and section 4 skips the default-thread timings; the hyperparameters stay matched.
    # Sections 5 and 6 run so little that process start-up dominates: a smoke run, not a figure.
    "quick": Sizes(
        env_steps=2_000,
        train_steps=2_000,
        team_steps=40,
        updates=200,
        eval_episodes=2,
        team_learning_starts=200,
        default_thread_timings=False,
        lone_steps=2_000,
        replica_steps=300,
        replica_counts=(1, 2),
        replica_learning_starts=100,
    ),
}

# Section 6: our process runs each engine on one thread (see the module docstring).
REPLICA_ENGINES = (Engine.numpy, Engine.torch)
REPLICA_THREADS = 1

METHOD = (
    "Each figure is the median of R interleaved repeats (the contenders of a comparison alternate "
    "order inside each repeat); each ratio is the median of the per-repeat paired ratios. Setup "
    "(networks, replay filling before learning_starts) is untimed. Two clocks: wall (time.perf_counter, "
    "what a user waits) and CPU (time.process_time, all threads of the process: what the work costs, "
    "much less disturbed by other jobs on a shared machine). Sections 5 and 6 time whole processes "
    "instead: wall from spawn to exit, CPU = user + system of the child (os.wait4). Compare ratios, not "
    "absolute figures, across machines."
)

ProgressFn = Callable[[str], None]


class Progress:
    """``[  3/40   12.1s] what`` lines on stderr."""

    def __init__(self, total: int):
        self.total, self.done, self.start = total, 0, time.perf_counter()

    def __call__(self, what: str) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.start
        print(f"[{self.done:>3}/{self.total} {elapsed:6.1f}s] {what}", file=sys.stderr, flush=True)


def median(values: Iterable[float]) -> float:
    return float(statistics.median(values))


def paired_ratio(a: Sequence[float], b: Sequence[float]) -> float:
    """Median over repeats of ``a[r] / b[r]``: each pair was measured back to back."""
    return median(x / y for x, y in zip(a, b))


def alternate(items: Sequence, repeat: int) -> Sequence:
    """``items`` in order on even repeats, reversed on odd ones: no contender always goes first."""
    return items if repeat % 2 == 0 else items[::-1]


def _version(distribution: str) -> str | None:
    try:
        return version(distribution)
    except PackageNotFoundError:
        return None


def _loadavg() -> list[float] | None:
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else None


def machine_info(threads_used: list[int]) -> dict[str, Any]:
    return {
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_available": cpus_available(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "gymnasium": _version("gymnasium"),
        "pettingzoo": _version("pettingzoo"),
        "stable_baselines3": _version("stable-baselines3"),
        "torch_default_threads": DEFAULT_THREADS,
        "torch_threads_used": threads_used,
    }


# ----------------------------------------------------------------------------- the six sections
def env_section(sizes: Sizes, seed: int, repeats: int, progress: ProgressFn) -> list[dict[str, Any]]:
    raw: dict[int, list[dict[str, Any]]] = {k: [] for k in ENV_AGENTS}
    for r in range(repeats):
        for k in ENV_AGENTS:
            raw[k].append(measure_env_throughput(k, sizes.env_steps, seed + r))
            progress(f"env throughput, {k} agent(s), repeat {r + 1}/{repeats}")
    return [
        {
            "num_agents": k,
            "steps": sizes.env_steps,
            "pettingzoo_steps_per_s": median(x["pettingzoo_steps_per_s"] for x in raw[k]),
            "core_steps_per_s": median(x["core_steps_per_s"] for x in raw[k]),
            "core_over_pettingzoo": paired_ratio(
                [x["core_steps_per_s"] for x in raw[k]], [x["pettingzoo_steps_per_s"] for x in raw[k]]
            ),
            "raw": raw[k],
        }
        for k in ENV_AGENTS
    ]


def training_section(
    sizes: Sizes, seed: int, repeats: int, train_threads: list[int], agent: AgentConfig, progress: ProgressFn
) -> list[dict[str, Any]]:
    measures = {"ours": measure_ours_training, "sb3": measure_sb3_training}
    raw: dict[int, dict[str, list[dict[str, Any]]]] = {t: {"ours": [], "sb3": []} for t in train_threads}
    for r in range(repeats):
        for t in train_threads:
            for who in alternate(("ours", "sb3"), r):
                torch.set_num_threads(t)
                out = measures[who](sizes.train_steps, seed + r, agent, eval_episodes=sizes.eval_episodes)
                raw[t][who].append(out)
                progress(
                    f"training {sizes.train_steps} steps, {'ours' if who == 'ours' else 'SB3 DQN'}, "
                    f"{t} thread(s), repeat {r + 1}/{repeats}: {out['steps_per_s']:.0f} steps/s"
                )
    rows = []
    for t in train_threads:
        runs = raw[t]
        # Each figure as its series over repeats, per contender.
        series = {who: {key: [run[key] for run in runs[who]] for key in runs[who][0]} for who in runs}
        ours, sb3 = series["ours"], series["sb3"]
        rows.append(
            {
                "torch_threads": t,
                "steps": sizes.train_steps,
                "ours_steps_per_s": median(ours["steps_per_s"]),
                "sb3_steps_per_s": median(sb3["steps_per_s"]),
                "ours_over_sb3": paired_ratio(ours["steps_per_s"], sb3["steps_per_s"]),
                "ours_steps_per_cpu_s": median(ours["steps_per_cpu_s"]),
                "sb3_steps_per_cpu_s": median(sb3["steps_per_cpu_s"]),
                "ours_over_sb3_cpu": paired_ratio(ours["steps_per_cpu_s"], sb3["steps_per_cpu_s"]),
                "ours_greedy_success": float(np.mean(ours["greedy_success"])),
                "sb3_greedy_success": float(np.mean(sb3["greedy_success"])),
                "ours_greedy_return": float(np.mean(ours["greedy_return"])),
                "sb3_greedy_return": float(np.mean(sb3["greedy_return"])),
                "raw": runs,
            }
        )
    return rows


def team_section(
    sizes: Sizes, seed: int, repeats: int, agent: AgentConfig, progress: ProgressFn
) -> list[dict[str, Any]]:
    rigs = {}
    for k in TEAM_SIZES:
        for separate in (False, True):
            rigs[k, separate] = TeamRig(k, separate, seed, agent)
            progress(f"team K={k}: {'separate learners' if separate else 'batched learner'} built, replay filled")
    wall: dict[tuple[int, bool], list[float]] = {key: [] for key in rigs}  # ms per joint step
    cpu: dict[tuple[int, bool], list[float]] = {key: [] for key in rigs}
    for r in range(repeats):
        for k in TEAM_SIZES:
            for separate in alternate((False, True), r):
                watch = rigs[k, separate].run(sizes.team_steps)
                wall[k, separate].append(1000.0 * watch.wall / sizes.team_steps)
                cpu[k, separate].append(1000.0 * watch.cpu / sizes.team_steps)
                progress(
                    f"team K={k}, {'separate' if separate else 'batched'}, repeat {r + 1}/{repeats}: "
                    f"{wall[k, separate][-1]:.2f} ms/step"
                )
    return [
        {
            "num_agents": k,
            "steps": sizes.team_steps,
            "batched_ms_per_step": median(wall[k, False]),
            "batched_ms_per_agent_step": median(wall[k, False]) / k,
            "separate_ms_per_step": median(wall[k, True]),
            "separate_ms_per_agent_step": median(wall[k, True]) / k,
            "separate_over_batched": paired_ratio(wall[k, True], wall[k, False]),
            "batched_over_k1": median(wall[k, False]) / median(wall[1, False]),
            "batched_cpu_ms_per_step": median(cpu[k, False]),
            "separate_cpu_ms_per_step": median(cpu[k, True]),
            "separate_over_batched_cpu": paired_ratio(cpu[k, True], cpu[k, False]),
            "batched_over_k1_cpu": median(cpu[k, False]) / median(cpu[1, False]),
            "raw_ms": {"batched": wall[k, False], "separate": wall[k, True]},
            "raw_cpu_ms": {"batched": cpu[k, False], "separate": cpu[k, True]},
        }
        for k in TEAM_SIZES
    ]


def update_section(
    sizes: Sizes,
    seed: int,
    repeats: int,
    threads: int,
    agent: AgentConfig,
    with_default_threads: bool,
    progress: ProgressFn,
) -> dict[str, Any]:
    rig = UpdateRig(seed, agent)
    progress("update rig built (DQNLearner K=1, bare nn.Sequential, bare BatchedMLP)")
    sb3_rig = SB3UpdateRig(seed, agent)
    progress("SB3 update rig built (replay filled)")

    def key(name: str, t: int) -> str:
        return name if t == threads else f"{name}_default_threads"

    # (name, torch threads): everything at `threads`, plus bare and ours at torch's default thread
    # count (time-capped: on an oversubscribed machine multi-threaded tiny updates can crawl).
    variants = [(name, threads) for name in UPDATE_NAMES]
    variants += [(name, DEFAULT_THREADS) for name in THREAD_NAMES if with_default_threads]
    wall: dict[str, list[float]] = {key(*v): [] for v in variants}  # us per update
    cpu: dict[str, list[float]] = {key(*v): [] for v in variants}
    for r in range(repeats):
        for name, t in alternate(variants, r):
            torch.set_num_threads(t)
            cap = None if t == threads else sizes.thread_cap_s
            w, c = sb3_rig.time(sizes.updates) if name == "sb3" else rig.time(name, sizes.updates, cap)
            wall[key(name, t)].append(w)
            cpu[key(name, t)].append(c)
            progress(f"gradient update: {name}, {t} thread(s), repeat {r + 1}/{repeats}: {w:.0f} us")
    torch.set_num_threads(threads)
    return {
        "updates": sizes.updates,
        "threads": threads,
        "default_threads": DEFAULT_THREADS,
        **{f"{name}_us": median(raw) for name, raw in wall.items()},
        **{f"{name}_cpu_us": median(raw) for name, raw in cpu.items()},
        **{f"{name}_over_bare": paired_ratio(raw, wall["bare"]) for name, raw in wall.items()},
        **{f"{name}_over_bare_cpu": paired_ratio(raw, cpu["bare"]) for name, raw in cpu.items()},
        "raw_us": wall,
        "raw_cpu_us": cpu,
    }


def _series(runs: list[dict[str, Any]], key: str) -> list[float]:
    return [run[key] for run in runs]


def _medians(runs: Sequence[dict[str, Any]], keys: Sequence[str]) -> dict[str, float]:
    """The median over repeats of each figure ``keys`` names."""
    return {key: median(_series(runs, key)) for key in keys}


def lone_section(sizes: Sizes, seed: int, repeats: int, progress: ProgressFn) -> dict[str, Any]:
    """Section 5: whole processes of ours, SB3 and bare PyTorch, one learner each, interleaved."""
    loadavg_start = _loadavg()
    raw: dict[str, list[dict[str, Any]]] = {who: [] for who in LONE_CONTENDERS}
    for r in range(repeats):
        for who in alternate(LONE_CONTENDERS, r):
            out = measure_lone(who, sizes.lone_steps, seed + r)
            raw[who].append(out)
            progress(
                f"lone learner, {who}, {sizes.lone_steps} steps, repeat {r + 1}/{repeats}: "
                f"{out['seconds']:.1f} s, {out['steps_per_s']:.0f} steps/s"
            )
    ours = raw["ours"]
    contenders = {
        who: {
            **_medians(runs, ("seconds", "cpu_seconds", "steps_per_s", "steps_per_cpu_s", "max_rss_mb")),
            "gradient_steps": runs[0]["gradient_steps"],
            # ours' rate over this one's (> 1: ours is faster), paired by repeat
            "ours_over_this": paired_ratio(_series(ours, "steps_per_s"), _series(runs, "steps_per_s")),
            "ours_over_this_cpu": paired_ratio(_series(ours, "steps_per_cpu_s"), _series(runs, "steps_per_cpu_s")),
        }
        for who, runs in raw.items()
    }
    return {
        "steps": sizes.lone_steps,
        "map": LONE_MAP,
        "hyperparameters": to_plain(LONE_AGENT),
        "contenders": contenders,
        **{f"ours_over_{who}": contenders[who]["ours_over_this"] for who in ("ours_torch", "sb3", "bare")},
        **{f"ours_over_{who}_cpu": contenders[who]["ours_over_this_cpu"] for who in ("ours_torch", "sb3", "bare")},
        "raw": raw,
        "loadavg_start": loadavg_start,
        "loadavg_end": _loadavg(),
    }


def replicas_section(sizes: Sizes, seed: int, repeats: int, cores: int, progress: ProgressFn) -> dict[str, Any]:
    """Section 6: learner-steps/s of one process of R replicas (for each R and each engine, one thread)
    against ``cores`` SB3 processes run side by side; the SB3 figure is measured once per repeat and
    paired with every row of that repeat."""
    loadavg_start = _loadavg()
    agent = dataclasses.replace(LONE_AGENT, learning_starts=sizes.replica_learning_starts)
    steps = sizes.replica_steps
    ours: dict[tuple[Engine, int], list[dict[str, Any]]] = {
        (engine, count): [] for engine in REPLICA_ENGINES for count in sizes.replica_counts
    }
    sb3: list[dict[str, Any]] = []
    for r in range(repeats):
        for who in alternate(("sb3", *ours), r):
            if who == "sb3":
                out = measure_sb3_parallel(cores, steps, seed + r, agent.learning_starts)
                sb3.append(out)
                label = f"{cores} SB3 processes side by side"
            else:
                engine, count = who
                out = measure_ours_replicas(
                    count, steps, seed + r, dataclasses.replace(agent, engine=engine), threads=REPLICA_THREADS
                )
                ours[who].append(out)
                label = f"ours, {engine.value} engine, {count} replica(s) in one process"
            progress(
                f"replicas, {label}, {steps} steps, repeat {r + 1}/{repeats}: {out['seconds']:.1f} s, "
                f"{out['learner_steps_per_s']:.0f} learner-steps/s"
            )
    sb3_rate, sb3_cpu_rate = _series(sb3, "learner_steps_per_s"), _series(sb3, "learner_steps_per_cpu_s")
    rows = [
        {
            "engine": engine.value,
            "replicas": count,
            "learners": count * TEAM_MAP["num_agents"],
            **_medians(
                runs, ("seconds", "cpu_seconds", "learner_steps_per_s", "learner_steps_per_cpu_s", "max_rss_mb")
            ),
            "gradient_steps": runs[0]["gradient_steps"],
            "ours_over_sb3": paired_ratio(_series(runs, "learner_steps_per_s"), sb3_rate),
            "ours_over_sb3_cpu": paired_ratio(_series(runs, "learner_steps_per_cpu_s"), sb3_cpu_rate),
            "raw": runs,
        }
        for (engine, count), runs in ours.items()
    ]
    return {
        "steps": steps,
        "learning_starts": agent.learning_starts,
        "team_agents": TEAM_MAP["num_agents"],
        "map": TEAM_MAP,
        "hyperparameters": to_plain(agent),
        "ours_threads": REPLICA_THREADS,
        "sb3_processes": cores,
        "sb3": {
            "seconds": median(_series(sb3, "seconds")),
            "cpu_seconds": median(_series(sb3, "cpu_seconds")),
            "learner_steps_per_s": median(sb3_rate),
            "learner_steps_per_cpu_s": median(sb3_cpu_rate),
            "max_rss_mb": median(_series(sb3, "max_rss_mb")),
            "gradient_steps": sb3[0]["gradient_steps"][0],
            "raw": sb3,
        },
        "rows": rows,
        "loadavg_start": loadavg_start,
        "loadavg_end": _loadavg(),
    }


# ----------------------------------------------------------------------------- the document
def run_benchmark(
    profile: str,
    seed: int,
    repeats: int,
    threads: int,
    train_threads: list[int] | None = None,
    sizes: Sizes | None = None,
    agent: AgentConfig = BENCH_AGENT,
    sections: Sequence[str] = SECTIONS,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """The measurements of ``sections`` (all six by default), as the JSON document.

    ``sizes`` defaults to ``PROFILES[profile]``; ``train_threads`` (torch threads of section 2) to
    ``[threads]``; ``progress`` to numbered lines on stderr.
    """
    sizes = PROFILES[profile] if sizes is None else sizes
    train_threads = [threads] if train_threads is None else list(train_threads)
    team_agent = (
        agent
        if sizes.team_learning_starts is None
        else dataclasses.replace(agent, learning_starts=sizes.team_learning_starts)
    )
    with_default_threads = sizes.default_thread_timings and threads != DEFAULT_THREADS
    if progress is None:
        steps = {
            "env": repeats * len(ENV_AGENTS),
            "training": repeats * len(train_threads) * 2,
            "team": 2 * len(TEAM_SIZES) + repeats * len(TEAM_SIZES) * 2,
            "update": 2 + repeats * (len(UPDATE_NAMES) + (len(THREAD_NAMES) if with_default_threads else 0)),
            "lone": repeats * len(LONE_CONTENDERS),
            "replicas": repeats * (1 + len(REPLICA_ENGINES) * len(sizes.replica_counts)),
        }
        progress = Progress(sum(steps[section] for section in sections))
    loadavg_start = _loadavg()
    results: dict[str, Any] = {}
    torch.set_num_threads(threads)
    if "env" in sections:
        results["env"] = env_section(sizes, seed, repeats, progress)
    if "training" in sections:
        results["training"] = training_section(sizes, seed, repeats, train_threads, agent, progress)
    torch.set_num_threads(threads)
    if "team" in sections:
        results["team"] = team_section(sizes, seed, repeats, team_agent, progress)
    if "update" in sections:
        results["update"] = update_section(sizes, seed, repeats, threads, agent, with_default_threads, progress)
    if "lone" in sections:
        results["lone"] = lone_section(sizes, seed, repeats, progress)
    if "replicas" in sections:
        results["replicas"] = replicas_section(sizes, seed, repeats, cpus_available(), progress)
    results["machine"] = {
        **machine_info(sorted({threads, *train_threads})),
        "loadavg_start": loadavg_start,
        "loadavg_end": _loadavg(),
    }
    results["settings"] = {
        "profile": profile,
        "seed": seed,
        "repeats": repeats,
        "threads": threads,
        "train_threads": train_threads,
        "sections": list(sections),
        **dataclasses.asdict(sizes),
        "replica_counts": list(sizes.replica_counts),
        "hyperparameters": to_plain(agent),
        "team_learning_starts": team_agent.learning_starts,
        "env_map": BENCH_MAP,
        "source_map": SOURCE_MAP,
    }
    results["method"] = METHOD
    return results


# ----------------------------------------------------------------------------- the table
def _fmt(x: float, digits: int = 0) -> str:
    return f"{x:,.{digits}f}"


def _part(
    heading: str, text: str, columns: Sequence[str], rows: Iterable[Sequence[str]], label_column: bool = False
) -> list[str]:
    """One section of the table: heading, explanation, and a Markdown table whose columns are right-aligned
    numbers (the first one left-aligned when it holds labels)."""
    align = ["---" if label_column else "---:"] + ["---:"] * (len(columns) - 1)
    return [
        heading,
        "",
        text,
        "",
        f"| {' | '.join(columns)} |",
        f"|{'|'.join(align)}|",
        *(f"| {' | '.join(row)} |" for row in rows),
    ]


def _x(ratio: float) -> str:
    return f"{ratio:.2f}x"


def _env_table(res: dict[str, Any]) -> list[str]:
    s = res["settings"]
    return _part(
        f"## 1. Environment throughput (random actions, {s['env_steps']:,} joint steps, resets included)",
        f"Map: {s['env_map']} generated for K starts. Wall clock.",
        ["agents", "PettingZoo ParallelEnv steps/s", "numpy core steps/s", "core / PettingZoo"],
        (
            [
                str(row["num_agents"]),
                _fmt(row["pettingzoo_steps_per_s"]),
                _fmt(row["core_steps_per_s"]),
                _x(row["core_over_pettingzoo"]),
            ]
            for row in res["env"]
        ),
    )


def _training_table(res: dict[str, Any]) -> list[str]:
    s = res["settings"]
    hp = s["hyperparameters"]
    return _part(
        f"## 2. DQN training on TreasureHunt-v0 ({s['train_steps']:,} env steps, "
        f"{max(0, s['train_steps'] - hp['learning_starts']):,} gradient steps)",
        f"Map: {s['source_map']} (one chest, 6 moves from the start). Ours: `Trainer(source_task=True).run()` "
        "(the training loop with its TensorBoard logging; progress bar off; its greedy evaluations and "
        'checkpoint writes timed and subtracted). SB3: `DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0"), '
        f"...).learn()`. Matched: net_arch {hp['hidden']}, lr {hp['lr']}, batch {hp['batch_size']}, buffer "
        f"{hp['buffer_size']:,}, learning_starts {hp['learning_starts']}, train_freq {hp['train_freq']}, "
        f"gradient_steps {hp['gradient_steps']}, target_update {hp['target_update']} (tau {hp['tau']}), "
        f"gamma {hp['gamma']}, epsilon {hp['eps_start']} -> {hp['eps_end']} over {hp['exploration_fraction']} "
        f"of the run, max_grad_norm {hp['max_grad_norm']}, Huber loss, Adam, CPU. Greedy success: fraction of "
        "greedy episodes reaching the chest after training (same episode loop for both), mean over repeats.",
        [
            "torch threads",
            "ours steps/s",
            "SB3 steps/s",
            "ours / SB3 (wall)",
            "ours / SB3 (CPU)",
            "ours greedy success",
            "SB3 greedy success",
        ],
        (
            [
                str(row["torch_threads"]),
                _fmt(row["ours_steps_per_s"]),
                _fmt(row["sb3_steps_per_s"]),
                _x(row["ours_over_sb3"]),
                _x(row["ours_over_sb3_cpu"]),
                _fmt(row["ours_greedy_success"], 2),
                _fmt(row["sb3_greedy_success"], 2),
            ]
            for row in res["training"]
        ),
    )


def _team_table(res: dict[str, Any]) -> list[str]:
    s = res["settings"]
    return _part(
        f"## 3. Per-step cost as the team grows ({s['team_steps']} timed joint steps, "
        "every one with a gradient update)",
        f"ms per joint env step = act + env step + replay store + gradient update (batch "
        f"{s['hyperparameters']['batch_size']} per agent), wall clock, after {s['team_learning_starts']} untimed "
        f"replay-filling steps; map {s['env_map']} generated for K starts, same hyperparameters. Batched: one "
        "DQNLearner for the K agents (stacked weights, one Adam step). Separate: K single-agent DQNLearners "
        "stepped in a Python loop.",
        [
            "K",
            "batched ms/step",
            "batched ms/agent-step",
            "batched vs K=1",
            "separate ms/step",
            "separate ms/agent-step",
            "separate / batched (wall)",
            "separate / batched (CPU)",
        ],
        (
            [
                str(row["num_agents"]),
                _fmt(row["batched_ms_per_step"], 2),
                _fmt(row["batched_ms_per_agent_step"], 2),
                _x(row["batched_over_k1"]),
                _fmt(row["separate_ms_per_step"], 2),
                _fmt(row["separate_ms_per_agent_step"], 2),
                _x(row["separate_over_batched"]),
                _x(row["separate_over_batched_cpu"]),
            ]
            for row in res["team"]
        ),
    )


UPDATE_LABELS = {
    "bare": "bare PyTorch, nn.Sequential, pre-sampled batch",
    "in_memory": "ours without the replay sample: DQNLearner.train_on(pre-sampled batch)",
    "ours": "DQNLearner.gradient_step (replay sample + update + per-agent loss/Q stats)",
    "sample": "of which ReplayBuffer.sample",
    "sb3": "SB3 DQN.train, per gradient step (replay sample included)",
    "bare_default_threads": "bare PyTorch, nn.Sequential, {threads} threads (torch default)",
    "ours_default_threads": "DQNLearner.gradient_step, {threads} threads (torch default)",
}


def _update_table(res: dict[str, Any]) -> list[str]:
    u = res["update"]
    return _part(
        f"## 4. Time per gradient update (K = 1, obs 100, batch {res['settings']['hyperparameters']['batch_size']}, "
        f"{u['updates']:,} updates per timing)",
        "Bare = CleanRL-style update of an nn.Sequential on a batch already in memory as tensors (target "
        "max under no_grad, gather, Huber loss, backward, clip_grad_norm_, Adam step).",
        ["update", "wall us/update", "CPU us/update", "vs bare (wall)", "vs bare (CPU)"],
        (
            [
                label.format(threads=u["default_threads"]),
                _fmt(u[f"{key}_us"]),
                _fmt(u[f"{key}_cpu_us"]),
                _x(u[f"{key}_over_bare"]),
                _x(u[f"{key}_over_bare_cpu"]),
            ]
            for key, label in UPDATE_LABELS.items()
            if f"{key}_us" in u
        ),
        label_column=True,
    )


def _machine_line(res: dict[str, Any], section: dict[str, Any]) -> str:
    """The machine, and the load average (1 min) when the section started and ended."""
    m, start, end = res["machine"], section.get("loadavg_start"), section.get("loadavg_end")
    load = (
        f"; load average (1 min) {start[0]:.2f} at the start of this section, {end[0]:.2f} at its end"
        if start and end
        else ""
    )
    return f"Machine: {m['cpu_model']}, {m['cpus_available']} cores{load}."


def _hyperparameters(hp: dict[str, Any]) -> str:
    return (
        f"MLP {hp['hidden']}, Adam lr {hp['lr']:g}, batch {hp['batch_size']}, replay {hp['buffer_size']:,}, "
        f"learning_starts {hp['learning_starts']:,}, train_freq {hp['train_freq']}, gradient_steps "
        f"{hp['gradient_steps']}, target copy every {hp['target_update']:,} steps (tau {hp['tau']}), gamma "
        f"{hp['gamma']}, epsilon {hp['eps_start']} -> {hp['eps_end']} over {hp['exploration_fraction']} of the "
        f"run, Huber loss, max_grad_norm {hp['max_grad_norm']}, CPU"
    )


def _map(kwargs: dict[str, Any]) -> str:
    return (
        f"{kwargs['size']}x{kwargs['size']} map ({kwargs['num_treasures']} chest(s), {kwargs['num_traps']} "
        f"trap(s), complexity {kwargs['complexity']}, map seed {kwargs['map_seed']})"
    )


LONE_LABELS = {
    "ours": "ours: `python -m dqn_transfer.cli.train agent.engine=numpy` (`train.py`)",
    "ours_torch": "ours, torch engine (the default): `python -m dqn_transfer.cli.train`",
    "sb3": 'SB3: `DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0")).learn()`',
    "bare": "bare PyTorch: a CleanRL-style dqn.py loop",
}


def _lone_table(res: dict[str, Any]) -> list[str]:
    lone = res["lone"]
    c = lone["contenders"]
    return _part(
        f"## 5. Whole process, one DQN learner ({lone['steps']:,} env steps, "
        f"{c['ours']['gradient_steps']:,} gradient steps)",
        f"{_machine_line(res, lone)} Settings: one agent on a {_map(lone['map'])}, each program trains "
        f"{lone['steps']:,} env steps with {_hyperparameters(lone['hyperparameters'])}, one torch thread. Wall: "
        "from spawn to exit (imports, setup, and ours' two one-episode evaluations, TensorBoard logging and "
        "final checkpoint included); CPU: user + system of the process (os.wait4). Ours observes the "
        "team game's position + chest-state inputs, SB3 and bare the position inputs of TreasureHunt-v0. "
        "ours / this: ours' steps/s over this program's, paired by repeat (> 1: ours is faster).",
        [
            "program",
            "wall s",
            "steps/s",
            "CPU s",
            "steps/CPU-s",
            "peak RSS MB",
            "gradient steps",
            "ours / this (wall)",
            "ours / this (CPU)",
        ],
        (
            [
                label,
                _fmt(c[who]["seconds"], 1),
                _fmt(c[who]["steps_per_s"]),
                _fmt(c[who]["cpu_seconds"], 1),
                _fmt(c[who]["steps_per_cpu_s"]),
                _fmt(c[who]["max_rss_mb"]),
                _fmt(c[who]["gradient_steps"]),
                _x(c[who]["ours_over_this"]),
                _x(c[who]["ours_over_this_cpu"]),
            ]
            for who, label in LONE_LABELS.items()
            if who in c
        ),
        label_column=True,
    )


def _replicas_table(res: dict[str, Any]) -> list[str]:
    rep = res["replicas"]
    sb3, k = rep["sb3"], rep["team_agents"]
    return _part(
        f"## 6. Sweep throughput: R replicas of a {k}-agent team in one process, against SB3 one learner "
        f"per process ({rep['steps']:,} env steps per process)",
        f"{_machine_line(res, rep)} Settings: a cooperative team of {k} DQN agents on a {_map(rep['map'])}, "
        f"{rep['steps']:,} joint env steps, {_hyperparameters(rep['hyperparameters'])}. Ours: ONE "
        "`python -m dqn_transfer.cli.train replicas.seeds=R agent.engine=E "
        f"threads={rep['ours_threads']}` process (R x {k} "
        f"learners, one batched learner); learner-steps/s = steps x R x {k} / whole-process wall. SB3: "
        f"{rep['sb3_processes']} `DQN.learn` processes (TreasureHunt-v0 of the map, one learner each, one "
        f"torch thread) started together; learner-steps/s = {rep['sb3_processes']} x steps / wall until the "
        f"last exits: {_fmt(sb3['learner_steps_per_s'])} (CPU: {_fmt(sb3['learner_steps_per_cpu_s'])} per "
        f"CPU-s), peak RSS {_fmt(sb3['max_rss_mb'])} MB per process. Measured once per repeat and paired with "
        "every R of that repeat (> 1: ours is faster).",
        [
            "engine",
            "R",
            "learners",
            "ours wall s",
            "ours learner-steps/s",
            "ours learner-steps/CPU-s",
            "ours peak RSS MB",
            "SB3 learner-steps/s",
            "ours / SB3 (wall)",
            "ours / SB3 (CPU)",
        ],
        (
            [
                row["engine"],
                str(row["replicas"]),
                str(row["learners"]),
                _fmt(row["seconds"], 1),
                _fmt(row["learner_steps_per_s"]),
                _fmt(row["learner_steps_per_cpu_s"]),
                _fmt(row["max_rss_mb"]),
                _fmt(sb3["learner_steps_per_s"]),
                _x(row["ours_over_sb3"]),
                _x(row["ours_over_sb3_cpu"]),
            ]
            for row in rep["rows"]
        ),
    )


TABLES = {
    "env": _env_table,
    "training": _training_table,
    "team": _team_table,
    "update": _update_table,
    "lone": _lone_table,
    "replicas": _replicas_table,
}


def render_markdown(res: dict[str, Any]) -> str:
    """The table of a :func:`run_benchmark` document: a header, then one part per measured section."""
    s, m = res["settings"], res["machine"]
    load = (
        f"; load average (1 min) at start {m['loadavg_start'][0]:.2f}, at end {m['loadavg_end'][0]:.2f}"
        if m.get("loadavg_start")
        else ""
    )
    lines = [
        f"# dqn_transfer benchmark ({s['profile']})",
        "",
        f"Method: {res['method']} R = {s['repeats']}, seed {s['seed']}, torch threads {s['threads']} unless stated.",
        "",
        f"Machine: {m['cpu_model']}, {m['cpus_available']} CPU(s) available ({m['cpu_count']} total), "
        f"torch {m['torch']} (default {m['torch_default_threads']} threads), SB3 {m['stable_baselines3']}, "
        f"gymnasium {m['gymnasium']}, PettingZoo {m['pettingzoo']}, Python {m['python']}{load}.",
    ]
    for section, table in TABLES.items():
        if section in res:
            lines += ["", *table(res)]
    lines.append("")
    return "\n".join(lines)
