"""Sections 5 and 6, whole processes: what a user waits for, from starting the command to its exit.

Sections 2-4 time loops inside one Python process and subtract what is not training. Here nothing is
subtracted: imports, building the networks, replay filling, the trainer's evaluations, TensorBoard
logging and checkpoint writes all count, as they do for whoever runs the command.

Section 5 (``lone``) runs one DQN learner on ``LONE_MAP`` as each of ``LONE_CONTENDERS`` (ours with either
engine, and the reference programs of :mod:`~dqn_transfer.benchmark.processes`); section 6 (``replicas``)
runs R replicas of a team on ``TEAM_MAP`` in ONE process of ours against one SB3 process per core.

Each child's wall time runs from just before it is spawned to the moment ``os.wait4`` reaps it; its CPU
time (user + system, all its threads) and peak resident memory are what ``os.wait4`` reports for it.
What a child did is read back after it has exited, untimed: ours from its checkpoints (every replica's
step and gradient-step count), the others from the JSON line they print last.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from enum import Enum
from pathlib import Path
from typing import Any

from dqn_transfer.benchmark.config import LONE_AGENT, LONE_MAP, TEAM_MAP, rates
from dqn_transfer.config import SB3_NAMES, AgentConfig
from dqn_transfer.enums import Engine
from dqn_transfer.storage.checkpoint import verify_checkpoint
from dqn_transfer.storage.run_dir import RunDir

LONE_CONTENDERS = ("ours", "ours_torch", "sb3", "bare")
# The engine of each of our contenders.
OUR_ENGINES = {"ours": Engine.numpy, "ours_torch": Engine.torch}
# Every AgentConfig key the programs are matched on, given to ours on its command line (so it trains
# with LONE_AGENT's values whatever the CLI's defaults are).
MATCHED_KEYS = ("hidden", "engine", *SB3_NAMES)


class ProcessFailed(RuntimeError):
    """A measured process exited non-zero; the message holds its command and the end of its stderr."""


def _override(value: Any) -> str:
    """A value as Hydra's command-line grammar writes it (``[64,64]``, ``cooperative``, ``0.0001``)."""
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_override(v) for v in value) + "]"
    if isinstance(value, Enum):
        return str(value.value)
    return str(value)


def train_command(
    run_dir: Path,
    steps: int,
    seed: int,
    agent: AgentConfig,
    env_kwargs: dict[str, Any],
    threads: int = 1,
    replicas: int = 1,
) -> list[str]:
    """``python -m dqn_transfer.cli.train`` with overrides for exactly ``agent`` and ``env_kwargs``.

    Evaluations and checkpoints as rarely as the trainer allows (at step 0 and at the end, one greedy
    episode per replica); progress bar off.

    :param run_dir: ``hydra.run.dir`` (must not hold a run)
    :param steps: ``total_steps``
    :param seed: ``seed`` (replica r gets ``seed + r``)
    :param agent: the DQN hyperparameters (and engine)
    :param env_kwargs: the ``env`` keys to set
    :param threads: ``threads``, torch's CPU threads
    :param replicas: ``replicas.seeds``
    """
    env = [f"env.{key}={_override(value)}" for key, value in env_kwargs.items()]
    hyperparameters = [f"agent.{key}={_override(getattr(agent, key))}" for key in MATCHED_KEYS]
    run = [
        f"seed={seed}",
        f"total_steps={steps}",
        f"eval_every={steps}",
        "eval_episodes=1",
        f"checkpoint_every={steps}",
    ]
    process = ["progress=false", f"threads={threads}", f"replicas.seeds={replicas}", f"hydra.run.dir={run_dir}"]
    return [sys.executable, "-m", "dqn_transfer.cli.train", *env, "agent=dqn", *hyperparameters, *run, *process]


def reference_command(
    program: str, steps: int, seed: int, map_name: str = "lone", learning_starts: int = LONE_AGENT.learning_starts
) -> list[str]:
    """``python -m dqn_transfer.benchmark.processes <program> ...`` (program: ``sb3`` or ``bare``).

    :param program: ``sb3`` or ``bare``
    :param steps: env steps
    :param seed: the program's seed
    :param map_name: ``lone`` (LONE_MAP) or ``bench`` (BENCH_MAP)
    :param learning_starts: env steps before the first update
    """
    options = ["--steps", str(steps), "--seed", str(seed), "--map", map_name, "--learning-starts", str(learning_starts)]
    return [sys.executable, "-m", "dqn_transfer.benchmark.processes", program, *options]


def run_together(
    commands: Sequence[Sequence[str]], cwd: Path | None = None, env: dict[str, str] | None = None
) -> dict[str, Any]:
    """Start every command at once and wait for all of them.

    Returns ``seconds`` (first spawn to last exit), ``cpu_seconds`` (summed over the processes) and
    ``processes``: per command its own wall seconds, CPU seconds, peak RSS (MB) and the JSON object of
    its last stdout line (None if that line is not JSON). Raises :class:`ProcessFailed` if any exits
    non-zero. If this is interrupted, it kills and reaps the processes it started.

    :param commands: the argv of each process
    :param cwd: their working directory (None: this one's)
    :param env: their environment (None: this one's)
    """
    n = len(commands)
    children: list[subprocess.Popen] = []
    starts: list[float] = []
    reaped: list[tuple[float, int, Any] | None] = [None] * n  # (exit time, wait status, rusage)

    def reap(i: int) -> None:  # one waiting thread per child, so that each exit is timed when it happens
        _, status, usage = os.wait4(children[i].pid, 0)
        reaped[i] = (time.perf_counter(), status, usage)

    with tempfile.TemporaryDirectory(prefix="dqn_transfer_bench_logs_") as tmp:
        logs = [(Path(tmp) / f"{i}.out", Path(tmp) / f"{i}.err") for i in range(n)]
        waiters: list[threading.Thread] = []
        try:
            for command, (out, err) in zip(commands, logs):
                with open(out, "wb") as stdout, open(err, "wb") as stderr:
                    starts.append(time.perf_counter())
                    children.append(
                        subprocess.Popen(
                            list(command), stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr, cwd=cwd, env=env
                        )
                    )
            waiters = [threading.Thread(target=reap, args=(i,), daemon=True) for i in range(n)]
            for waiter in waiters:
                waiter.start()
            for waiter in waiters:
                waiter.join()
        finally:
            if None in reaped:  # interrupted (or a spawn failed): stop what was started, and reap it
                for i, child in enumerate(children):
                    if reaped[i] is None:
                        child.kill()
                for waiter in waiters:
                    waiter.join()
                for i, child in enumerate(children):
                    if reaped[i] is None and not waiters:
                        os.wait4(child.pid, 0)
                    child.returncode = -9
        finished = [r for r in reaped if r is not None]  # all of them: the finally above raised otherwise
        processes = []
        for i, (command, child, start) in enumerate(zip(commands, children, starts)):
            end, status, usage = finished[i]
            child.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
            if child.returncode != 0:
                tail = "\n".join(logs[i][1].read_text(errors="replace").strip().splitlines()[-15:])
                raise ProcessFailed(f"{' '.join(command)} exited with {child.returncode}:\n{tail}")
            processes.append(
                {
                    "seconds": end - start,
                    "cpu_seconds": usage.ru_utime + usage.ru_stime,
                    "max_rss_mb": usage.ru_maxrss / 1024.0,  # Linux reports kilobytes
                    "report": _last_json(logs[i][0].read_text(errors="replace")),
                }
            )
    return {
        "seconds": max(r[0] for r in finished) - min(starts),
        "cpu_seconds": sum(p["cpu_seconds"] for p in processes),
        "processes": processes,
    }


def _last_json(text: str) -> dict[str, Any] | None:
    lines = text.strip().splitlines()
    try:
        return json.loads(lines[-1]) if lines else None
    except ValueError:
        return None


def trainer_report(run_dir: Path) -> dict[str, Any]:
    """What a finished ``train`` process did, from its checkpoints: replicas, and per replica its steps,
    gradient steps and episodes."""
    run = RunDir(run_dir)
    dirs = run.replica_dirs() or [run.path]
    metas = [verify_checkpoint(RunDir(d).training_state, "training_state").meta for d in dirs]
    return {
        "replicas": len(dirs),
        "steps": [m["counters"]["step"] for m in metas],
        "gradient_steps": [m["learner"]["num_gradient_steps"] for m in metas],
        "episodes": [m["counters"]["episodes"] for m in metas],
    }


def _figures(steps: int, timing: dict[str, Any], learners: int = 1) -> dict[str, Any]:
    """Wall and CPU seconds of a run of ``learners`` x ``steps`` learner-steps, and the rates."""
    wall, cpu = timing["seconds"], timing["cpu_seconds"]
    return {
        **rates(steps, wall, cpu),
        "learners": learners,
        "learner_steps_per_s": learners * steps / wall,
        "learner_steps_per_cpu_s": learners * steps / cpu,
        "max_rss_mb": max(p["max_rss_mb"] for p in timing["processes"]),
    }


# ----------------------------------------------------------------------------- 5. lone learner
def measure_lone(who: str, steps: int, seed: int) -> dict[str, Any]:
    """One whole process of ``who`` training one learner on ``LONE_MAP`` for ``steps``.

    :param who: one of ``LONE_CONTENDERS``
    :param steps: env steps
    :param seed: the run's seed
    """
    if who in OUR_ENGINES:
        agent = dataclasses.replace(LONE_AGENT, engine=OUR_ENGINES[who])
        with tempfile.TemporaryDirectory(prefix="dqn_transfer_bench_") as tmp:
            run_dir = Path(tmp) / "run"
            timing = run_together([train_command(run_dir, steps, seed, agent, {**LONE_MAP, "num_agents": 1})])
            report = {key: values[0] for key, values in trainer_report(run_dir).items() if key != "replicas"}
    else:
        timing = run_together([reference_command(who, steps, seed)])
        report = timing["processes"][0]["report"]
    done = {"gradient_steps": report["gradient_steps"], "episodes": report["episodes"], "steps_done": report["steps"]}
    return {**_figures(steps, timing), **done}


# ----------------------------------------------------------------------------- 6. replicas
def measure_ours_replicas(replicas: int, steps: int, seed: int, agent: AgentConfig, threads: int) -> dict[str, Any]:
    """One ``train`` process of ``replicas`` replicas of the 4-agent team (``TEAM_MAP``) for ``steps``.

    :param replicas: ``replicas.seeds``
    :param steps: joint env steps
    :param seed: the first replica's seed
    :param agent: the hyperparameters
    :param threads: torch threads of the process
    """
    with tempfile.TemporaryDirectory(prefix="dqn_transfer_bench_") as tmp:
        run_dir = Path(tmp) / "run"
        timing = run_together([train_command(run_dir, steps, seed, agent, TEAM_MAP, threads, replicas)])
        report = trainer_report(run_dir)
    return {
        **_figures(steps, timing, replicas * TEAM_MAP["num_agents"]),
        "replicas": replicas,
        "threads": threads,
        "replica_dirs": report["replicas"],
        "replica_steps": report["steps"],
        "gradient_steps": report["gradient_steps"][0],
        "episodes": sum(report["episodes"]),
    }


def measure_sb3_parallel(processes: int, steps: int, seed: int, learning_starts: int) -> dict[str, Any]:
    """``processes`` SB3 processes started together, one learner each on ``TreasureHunt-v0`` of
    ``BENCH_MAP``; wall time until the last exits.

    :param processes: how many (one per core)
    :param steps: env steps per process
    :param seed: process i gets ``seed + i``
    :param learning_starts: env steps before the first update
    """
    timing = run_together(
        [reference_command("sb3", steps, seed + i, "bench", learning_starts) for i in range(processes)]
    )
    reports = [p["report"] for p in timing["processes"]]
    return {
        **_figures(steps, timing, processes),
        "processes": processes,
        "process_seconds": [p["seconds"] for p in timing["processes"]],
        "process_steps": [r["steps"] for r in reports],
        "gradient_steps": [r["gradient_steps"] for r in reports],
        "episodes": [r["episodes"] for r in reports],
    }
