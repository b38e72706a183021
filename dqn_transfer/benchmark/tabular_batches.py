"""Section 7, ``tabular``: the study's tabular runs as replicas, this checkout against an earlier one.

A study job is one process of R replicas of a 4-agent SARSA team (``env=study/m4``). What a study pays
per env step is the *marginal* cost: the wall time of a ``total_steps=long`` process minus that of a
``total_steps=short`` one (start-up, config writing and the final checkpoint cancel), over
``long - short`` joint steps. Each figure is measured for this checkout and, with ``--baseline DIR``,
for another checkout of the project (e.g. ``git worktree add /tmp/v0 <commit>``: the per-replica path
before the batched core), whose own ``train.py`` runs with ``PYTHONPATH=DIR`` so that it imports its
own package. Both get the same command line, which every version of the CLI since the study accepts.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path
from typing import Any

from dqn_transfer.benchmark.whole_process import run_together

TABULAR_ENV = "study/m4"  # 8x8, 4 agents, 4 chests, 4 traps: the study's main setting
TABULAR_AGENTS = 4  # that setting's team
TABULAR_EVAL_EVERY = 500  # the study's evaluation interval


def tabular_command(checkout: Path | None, run_dir: Path, steps: int, replicas: int, mode: str, seed: int) -> list[str]:
    """The training command of ``checkout``: ``replicas`` replicas of the SARSA team on ``TABULAR_ENV``.

    :param checkout: the project directory whose ``train.py`` runs (None: this package's
        ``python -m dqn_transfer.cli.train``)
    :param run_dir: ``hydra.run.dir`` (must not hold a run)
    :param steps: ``total_steps`` (one checkpoint, at the end)
    :param replicas: ``replicas.seeds``
    :param mode: ``competitive``, ``cooperative`` or ``deliberative``
    :param seed: the first replica's seed
    """
    program = ["-m", "dqn_transfer.cli.train"] if checkout is None else [str(checkout / "train.py")]
    game = ["agent=sarsa", f"env={TABULAR_ENV}", f"mode={mode}", f"replicas.seeds={replicas}", f"seed={seed}"]
    run = [f"total_steps={steps}", f"eval_every={TABULAR_EVAL_EVERY}", f"checkpoint_every={steps}", "progress=false"]
    return [sys.executable, *program, *game, *run, f"hydra.run.dir={run_dir}"]


def measure_marginal(
    checkout: Path | None, replicas: int, mode: str, short: int, long: int, seed: int
) -> dict[str, Any]:
    """Two whole processes of ``checkout`` (``short`` then ``long`` steps) and the difference: wall and
    CPU seconds per 1,000 joint steps, and agent-steps/s of the difference.

    :param checkout: the project directory to run, with its own package (None: this package)
    :param replicas: ``replicas.seeds``
    :param mode: the game's mode
    :param short: ``total_steps`` of the first process
    :param long: ``total_steps`` of the second (> ``short``)
    :param seed: the first replica's seed
    """
    environment = None if checkout is None else {**os.environ, "PYTHONPATH": str(checkout)}
    timings = []
    with tempfile.TemporaryDirectory(prefix="dqn_transfer_bench_") as tmp:
        for steps in (short, long):
            command = tabular_command(checkout, Path(tmp) / str(steps), steps, replicas, mode, seed)
            timings.append(run_together([command], cwd=checkout, env=environment))
    wall = timings[1]["seconds"] - timings[0]["seconds"]
    cpu = timings[1]["cpu_seconds"] - timings[0]["cpu_seconds"]
    per_thousand = 1000 / (long - short)
    return {
        "short_seconds": timings[0]["seconds"],
        "long_seconds": timings[1]["seconds"],
        "seconds_per_1k_steps": wall * per_thousand,
        "cpu_seconds_per_1k_steps": cpu * per_thousand,
        "agent_steps_per_s": (long - short) * replicas * TABULAR_AGENTS / wall if wall > 0 else float("inf"),
        "max_rss_mb": max(t["processes"][0]["max_rss_mb"] for t in timings),
    }
