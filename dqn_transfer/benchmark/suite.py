"""The driver: the seven measurements, interleaved repeats, paired ratios, summarised as a JSON document.

Threads. Sections 1-4 run at ``threads`` torch threads (the CLI's default is 1: for networks this
small, intra-op parallelism costs more in synchronisation than it gains, and on a busy machine a second
thread that has to wait for a core can make an update tens of times slower). Section 4 shows the
default-thread figure beside it; the default-thread update timings stop after ``thread_cap_s``. Section
5's processes run on one thread each; in section 6 SB3 gets every core (one single-threaded process
per core) and ours one command whose replicas are split across worker processes, one per core
(``replicas.workers=auto``), each on one thread: both engines, whose second torch thread measured slower
here (spin-waiting for a core that SB3's processes, or any other job, hold).

Method: :data:`METHOD` (the machine may be shared and noisy: medians of interleaved repeats, paired ratios,
two clocks); sections 5 to 7 also record the load average at their own start and end, since a
process-level figure is the most exposed to other jobs.
:func:`run_benchmark` returns everything, with the raw per-repeat figures and the machine, as the JSON
document (plain dicts: each figure the median over repeats, each ratio the median of the per-repeat paired
ratios, ``raw`` what every repeat measured); :func:`~dqn_transfer.benchmark.tables.render_markdown` makes
the table of it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import Enum
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dqn_transfer.benchmark.config import BENCH_AGENT, BENCH_MAP, LONE_AGENT, LONE_MAP, SOURCE_MAP, TEAM_MAP
from dqn_transfer.benchmark.env_throughput import measure_env_throughput
from dqn_transfer.benchmark.tabular_batches import TABULAR_AGENTS, TABULAR_ENV, TABULAR_EVAL_EVERY, measure_marginal
from dqn_transfer.benchmark.team_scaling import TeamRig
from dqn_transfer.benchmark.training import measure_training
from dqn_transfer.benchmark.update_cost import THREAD_NAMES, UPDATE_NAMES, SB3UpdateRig, UpdateRig
from dqn_transfer.benchmark.whole_process import (
    LONE_CONTENDERS,
    measure_lone,
    measure_ours_replicas,
    measure_sb3_parallel,
)
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Engine
from dqn_transfer.timing import cpu_model, cpus_available

SECTIONS = ("env", "training", "team", "update", "lone", "replicas", "tabular")
NEEDS_SB3 = ("training", "update", "lone", "replicas")
ENV_AGENTS = (1, 4, 8)
TEAM_SIZES = (1, 2, 4, 8)
DEFAULT_THREADS = torch.get_num_threads()  # torch's own choice on this machine, read before any change


@dataclass(frozen=True)
class Sizes:
    """How much each measurement does per repeat; the defaults are the ``full`` profile."""

    env_steps: int = 20_000  # section 1: joint steps per path
    train_steps: int = 10_000  # section 2: env steps per training run
    team_steps: int = 400  # section 3: timed joint steps per rig
    updates: int = 2_000  # section 4: gradient updates per timing
    eval_episodes: int = 5  # section 2: greedy episodes after training
    thread_cap_s: float = 3.0  # section 4: time limit of a default-thread timing
    team_learning_starts: int | None = None  # section 3: replay filled before timing (None: the agent's)
    default_thread_timings: bool = True  # section 4: also time bare and ours at torch's default threads
    lone_steps: int = 10_000  # section 5: env steps per process
    replica_steps: int = 3_000  # section 6: joint env steps per process
    replica_counts: tuple[int, ...] = (1, 4, 10, 16, 64)  # section 6: replicas.seeds of our processes
    replica_learning_starts: int = 500  # section 6: env steps before the first update, ours and SB3's
    tabular_steps: tuple[int, int] = (1_000, 4_000)  # section 7: total_steps of the short and long process
    tabular_counts: tuple[int, ...] = (1, 10, 100)  # section 7: replicas.seeds
    tabular_modes: tuple[str, ...] = ("cooperative", "deliberative")  # section 7


PROFILES = {
    "full": Sizes(),
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
        tabular_steps=(20, 60),
        tabular_counts=(1, 4),
        tabular_modes=("cooperative",),
    ),
}

# Section 6: our command runs each engine on one thread a process (see the module docstring).
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


def _load(start: list[float] | None) -> dict[str, list[float] | None]:
    """The load average (1, 5, 15 min) at a section's ``start`` and now; None where the OS has none."""
    return {"start": start, "end": _loadavg()}


def machine_info(threads_used: list[int], loadavg_start: list[float] | None) -> dict[str, Any]:
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
        "load": _load(loadavg_start),
    }


Runs = Sequence[dict[str, Any]]  # one measurement's figures per repeat, as the measuring function reported them


def _series(runs: Runs, key: str) -> list[float]:
    return [run[key] for run in runs]


def _ratio(a: Runs, b: Runs, key: str, key_b: str | None = None) -> float:
    """:func:`paired_ratio` of the repeats' ``key`` in ``a`` over ``key_b`` (default ``key``) in ``b``."""
    return paired_ratio(_series(a, key), _series(b, key_b or key))


def _medians(runs: Runs, *keys: str) -> dict[str, float]:
    """The median over repeats of each figure of ``keys``."""
    return {key: median(_series(runs, key)) for key in keys}


# ----------------------------------------------------------------------------- the sections
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
            **_medians(runs, "pettingzoo_steps_per_s", "core_steps_per_s"),
            "core_over_pettingzoo": _ratio(runs, runs, "core_steps_per_s", "pettingzoo_steps_per_s"),
            "raw": runs,
        }
        for k, runs in raw.items()
    ]


def _contender(runs: Runs) -> dict[str, float]:
    """A trainer's figures at one thread count; the greedy ones are means over repeats."""
    return {
        **_medians(runs, "steps_per_s", "steps_per_cpu_s"),
        **{key: float(np.mean(_series(runs, key))) for key in ("greedy_success", "greedy_return")},
    }


def training_section(
    sizes: Sizes, seed: int, repeats: int, train_threads: list[int], agent: AgentConfig, progress: ProgressFn
) -> list[dict[str, Any]]:
    raw: dict[int, dict[str, list[dict[str, Any]]]] = {t: {"ours": [], "sb3": []} for t in train_threads}
    for r in range(repeats):
        for t in train_threads:
            for who in alternate(("ours", "sb3"), r):
                torch.set_num_threads(t)
                out = measure_training(who, sizes.train_steps, seed + r, agent, eval_episodes=sizes.eval_episodes)
                raw[t][who].append(out)
                progress(
                    f"training {sizes.train_steps} steps, {'ours' if who == 'ours' else 'SB3 DQN'}, "
                    f"{t} thread(s), repeat {r + 1}/{repeats}: {out['steps_per_s']:.0f} steps/s"
                )
    return [
        {
            "torch_threads": t,
            "steps": sizes.train_steps,
            "ours": _contender(runs["ours"]),
            "sb3": _contender(runs["sb3"]),
            "ours_over_sb3": _ratio(runs["ours"], runs["sb3"], "steps_per_s"),
            "ours_over_sb3_cpu": _ratio(runs["ours"], runs["sb3"], "steps_per_cpu_s"),
            "raw": runs,
        }
        for t, runs in raw.items()
    ]


def _step_cost(wall: list[float], cpu: list[float], k: int) -> dict[str, Any]:
    """One learner layout's ms per joint step: wall and CPU, and per repeat."""
    return {
        "ms_per_step": median(wall),
        "ms_per_agent_step": median(wall) / k,
        "cpu_ms_per_step": median(cpu),
        "raw_ms": wall,
        "raw_cpu_ms": cpu,
    }


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
            "batched": _step_cost(wall[k, False], cpu[k, False], k),
            "separate": _step_cost(wall[k, True], cpu[k, True], k),
            "separate_over_batched": paired_ratio(wall[k, True], wall[k, False]),
            "separate_over_batched_cpu": paired_ratio(cpu[k, True], cpu[k, False]),
            "batched_over_k1": median(wall[k, False]) / median(wall[1, False]),
            "batched_over_k1_cpu": median(cpu[k, False]) / median(cpu[1, False]),
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
    """Section 4: us per update of each kind (``<name>_default_threads`` at torch's default thread count),
    and against the bare PyTorch update."""
    rig = UpdateRig(seed, agent)
    progress("update rig built (DQNLearner K=1, bare nn.Sequential)")
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
    timings = {
        name: {
            "wall_us": median(wall[name]),
            "cpu_us": median(cpu[name]),
            "over_bare": paired_ratio(wall[name], wall["bare"]),
            "over_bare_cpu": paired_ratio(cpu[name], cpu["bare"]),
            "raw_us": wall[name],
            "raw_cpu_us": cpu[name],
        }
        for name in wall
    }
    return {"updates": sizes.updates, "threads": threads, "default_threads": DEFAULT_THREADS, "timings": timings}


def _process_figures(runs: Runs, rate: str, gradient_steps: int) -> dict[str, Any]:
    """The median over repeats of each whole-process figure; ``rate``: ``steps`` or ``learner_steps``."""
    rates = {f"steps_{per}": median(_series(runs, f"{rate}_{per}")) for per in ("per_s", "per_cpu_s")}
    return {**_medians(runs, "seconds", "cpu_seconds", "max_rss_mb"), **rates, "gradient_steps": gradient_steps}


def lone_section(sizes: Sizes, seed: int, repeats: int, progress: ProgressFn) -> dict[str, Any]:
    """Section 5: whole processes of ours, SB3 and bare PyTorch, one learner each, interleaved;
    ``ours_over_this``: ours' rate over each one's, paired by repeat (> 1: ours is faster)."""
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
    contenders = {
        who: {
            "figures": _process_figures(runs, "steps", runs[0]["gradient_steps"]),
            "ours_over_this": _ratio(raw["ours"], runs, "steps_per_s"),
            "ours_over_this_cpu": _ratio(raw["ours"], runs, "steps_per_cpu_s"),
            "raw": runs,
        }
        for who, runs in raw.items()
    }
    return {
        "steps": sizes.lone_steps,
        "map": LONE_MAP,
        "hyperparameters": LONE_AGENT,
        "contenders": contenders,
        "load": _load(loadavg_start),
    }


def replicas_section(sizes: Sizes, seed: int, repeats: int, cores: int, progress: ProgressFn) -> dict[str, Any]:
    """Section 6: learner-steps/s of one command of R replicas (for each R and each engine, one thread a process)
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
            if isinstance(who, str):
                out = measure_sb3_parallel(cores, steps, seed + r, agent.learning_starts)
                sb3.append(out)
                label = f"{cores} SB3 processes side by side"
            else:
                engine, count = who
                out = measure_ours_replicas(
                    count, steps, seed + r, dataclasses.replace(agent, engine=engine), threads=REPLICA_THREADS
                )
                ours[who].append(out)
                label = f"ours, {engine.value} engine, {count} replica(s) in one command"
            progress(
                f"replicas, {label}, {steps} steps, repeat {r + 1}/{repeats}: {out['seconds']:.1f} s, "
                f"{out['learner_steps_per_s']:.0f} learner-steps/s"
            )
    team = TEAM_MAP["num_agents"]
    rows = [
        {
            "engine": engine.value,
            "replicas": count,
            "learners": count * team,
            "figures": _process_figures(runs, "learner_steps", runs[0]["gradient_steps"]),
            "ours_over_sb3": _ratio(runs, sb3, "learner_steps_per_s"),
            "ours_over_sb3_cpu": _ratio(runs, sb3, "learner_steps_per_cpu_s"),
            "raw": runs,
        }
        for (engine, count), runs in ours.items()
    ]
    return {
        "steps": steps,
        "learning_starts": agent.learning_starts,
        "team_agents": team,
        "map": TEAM_MAP,
        "hyperparameters": agent,
        "ours_threads": REPLICA_THREADS,
        "sb3_processes": cores,
        "sb3": _process_figures(sb3, "learner_steps", sb3[0]["gradient_steps"][0]),  # the processes side by side
        "sb3_raw": sb3,
        "rows": rows,
        "load": _load(loadavg_start),
    }


def _git_commit(checkout: Path) -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(checkout), "rev-parse", "HEAD"], capture_output=True, text=True)
    except OSError:  # no git
        return None
    return done.stdout.strip() if done.returncode == 0 else None


MARGINAL_FIGURES = ("seconds_per_1k_steps", "cpu_seconds_per_1k_steps", "agent_steps_per_s", "max_rss_mb")


def tabular_section(
    sizes: Sizes, seed: int, repeats: int, baseline: Path | None, progress: ProgressFn
) -> dict[str, Any]:
    """Section 7: per mode and R, the marginal cost of this checkout's process of R SARSA replicas and,
    with ``baseline``, of that checkout's, the two alternating within each repeat; ``speedup``: the
    baseline's seconds per step over ours', paired by repeat (> 1: ours is faster; None without a baseline)."""
    loadavg_start = _loadavg()
    checkouts = {"ours": None, **({"baseline": baseline} if baseline is not None else {})}
    short, long = sizes.tabular_steps
    paired = baseline is not None

    def row(mode: str, count: int) -> dict[str, Any]:
        raw: dict[str, list[dict[str, Any]]] = {who: [] for who in checkouts}
        for r in range(repeats):
            for who in alternate(list(checkouts), r):
                out = measure_marginal(checkouts[who], count, mode, short, long, seed + r)
                raw[who].append(out)
                progress(
                    f"tabular, {who}, {mode}, {count} replica(s), repeat {r + 1}/{repeats}: "
                    f"{out['seconds_per_1k_steps']:.2f} s per 1,000 steps"
                )
        figures = {who: _medians(runs, *MARGINAL_FIGURES) for who, runs in raw.items()}
        return {
            "mode": mode,
            "replicas": count,
            "ours": figures["ours"],
            "baseline": figures.get("baseline"),
            "speedup": _ratio(raw["baseline"], raw["ours"], "seconds_per_1k_steps") if paired else None,
            "speedup_cpu": _ratio(raw["baseline"], raw["ours"], "cpu_seconds_per_1k_steps") if paired else None,
            "raw": raw,
        }

    return {
        "env": TABULAR_ENV,
        "agents": TABULAR_AGENTS,
        "steps": [short, long],
        "eval_every": TABULAR_EVAL_EVERY,
        "baseline": None if baseline is None else str(baseline),
        "baseline_commit": None if baseline is None else _git_commit(baseline),
        "rows": [row(mode, count) for mode in sizes.tabular_modes for count in sizes.tabular_counts],
        "load": _load(loadavg_start),
    }


# ----------------------------------------------------------------------------- the document
def _plain(value: Any) -> Any:
    if isinstance(value, Enum):
        return value.value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    raise TypeError(f"{type(value).__name__} is not JSON")


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
    baseline: Path | None = None,
) -> dict[str, Any]:
    """The JSON document of the measurements of ``sections`` (all seven by default), in plain JSON types;
    a section not measured is left out.

    ``sizes`` defaults to ``PROFILES[profile]``; ``train_threads`` (torch threads of section 2) to
    ``[threads]``; ``progress`` to numbered lines on stderr; ``baseline``: the earlier checkout section 7
    runs beside this one (None: this one alone).
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
            "tabular": repeats * len(sizes.tabular_modes) * len(sizes.tabular_counts) * (1 if baseline is None else 2),
        }
        progress = Progress(sum(steps[section] for section in sections))
    measures: dict[str, Callable[[ProgressFn], Any]] = {  # in table order
        "env": lambda p: env_section(sizes, seed, repeats, p),
        "training": lambda p: training_section(sizes, seed, repeats, train_threads, agent, p),
        "team": lambda p: team_section(sizes, seed, repeats, team_agent, p),
        "update": lambda p: update_section(sizes, seed, repeats, threads, agent, with_default_threads, p),
        "lone": lambda p: lone_section(sizes, seed, repeats, p),
        "replicas": lambda p: replicas_section(sizes, seed, repeats, cpus_available(), p),
        "tabular": lambda p: tabular_section(sizes, seed, repeats, baseline, p),
    }
    loadavg_start = _loadavg()
    measured = {}
    for section, measure in measures.items():
        if section in sections:
            torch.set_num_threads(threads)  # section 2 changes it
            measured[section] = measure(progress)
    settings = {
        "profile": profile,
        "seed": seed,
        "repeats": repeats,
        "threads": threads,
        "train_threads": train_threads,
        "sections": list(sections),
        "sizes": sizes,
        "hyperparameters": agent,
        "team_learning_starts": team_agent.learning_starts,
        "env_map": BENCH_MAP,
        "source_map": SOURCE_MAP,
    }
    machine = machine_info(sorted({threads, *train_threads}), loadavg_start)
    document = {"settings": settings, "machine": machine, "method": METHOD, **measured}
    return json.loads(json.dumps(document, default=_plain))  # enums by value, dataclasses as dicts, tuples as lists
