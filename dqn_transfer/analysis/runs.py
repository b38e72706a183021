"""Reading run directories: their evaluations (``metrics.jsonl``) and their Hydra configs.

A run directory is laid out as :mod:`dqn_transfer.run_dir` says. Evaluations are read from the file,
never from live objects, so runs from any machine or SLURM job can be analysed; a run that is still
writing, or was killed mid-write, is read up to its last complete line.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml

from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.run_dir import CONFIG_FILE, HYDRA_DIR, METRICS_FILE, RunDir, natural_key

K = TypeVar("K")


class EvaluationError(Exception):
    """A run directory or its metrics cannot be used; the message is one user-facing line."""


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, Any]]:
    """All evaluation records of a run, in file order.

    A last line without its newline that does not parse is a write cut short by a killed run: it
    is skipped with a warning. Any other bad line is an error.
    """
    path = RunDir(run_dir).metrics
    if not Path(run_dir).exists():
        raise EvaluationError(f"{run_dir}: no such run directory")
    if not Path(run_dir).is_dir():
        raise EvaluationError(f"{run_dir}: not a directory (expected a run directory)")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise EvaluationError(f"{path}: missing; {run_dir} has no evaluations (not a run directory, "
                              "or the run has not evaluated yet)") from None
    lines = text.split("\n")
    records = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):  # no trailing newline: interrupted append
                warnings.warn(f"{path}: skipping incomplete last line {number}", stacklevel=2)
                continue
            raise EvaluationError(f"{path}: line {number} is not valid JSON") from None
        if not isinstance(record, dict):
            raise EvaluationError(f"{path}: line {number} is not a JSON object")
        records.append(record)
    return records


def learning_curve(run_dir: str | os.PathLike, metric: str = "team_return") -> Curve:
    """``(steps, values)`` of ``metric`` over a run's evaluations, sorted by step.

    A resumed run re-evaluates the steps after its last checkpoint; for a repeated step the later
    record wins, since it belongs to the run that continued.
    """
    records = read_metrics(run_dir)
    by_step: dict[int, float] = {}
    for record in records:
        if isinstance(record.get(metric), (int, float)) and "step" in record:
            by_step[int(record["step"])] = float(record[metric])
    if not by_step:
        available = sorted({key for record in records for key, value in record.items()
                            if isinstance(value, (int, float))} - {"step"})
        raise EvaluationError(f"{RunDir(run_dir).metrics}: no {metric!r} evaluations "
                              f"(available: {', '.join(available) or 'none'})")
    steps = np.array(sorted(by_step), dtype=np.float64)
    return steps, np.array([by_step[int(s)] for s in steps], dtype=np.float64)


def find_run_dirs(paths: Sequence[str | os.PathLike]) -> list[Path]:
    """The run directories at or below ``paths`` (those holding ``metrics.jsonl``), naturally sorted."""
    runs: list[Path] = []
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise EvaluationError(f"{path}: no such directory")
        if RunDir(path).has_metrics():
            runs.append(path)
            continue
        found = sorted((p.parent for p in path.rglob(METRICS_FILE)), key=natural_key)
        if not found:
            raise EvaluationError(f"{path}: holds no run directory (no {METRICS_FILE} at or below it)")
        runs.extend(found)
    return list(dict.fromkeys(p.resolve() for p in runs))


def load_config(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The run's composed Hydra config (``.hydra/config.yaml``), or None if unreadable."""
    try:
        config = yaml.safe_load(RunDir(run_dir).config.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return config if isinstance(config, dict) else None


def run_seed(run_dir: str | os.PathLike) -> int | None:
    """The run's ``seed`` from its Hydra config, if readable."""
    seed = (load_config(run_dir) or {}).get("seed")
    return seed if isinstance(seed, int) else None


@dataclass
class Run:
    """A run directory with its config, for analyses that tell conditions apart by config values."""

    dir: Path
    config: dict[str, Any]

    @property
    def seed(self) -> int:
        return int(self.config.get("seed", 0))

    def curve(self, metric: str = "team_return") -> Curve:
        return learning_curve(self.dir, metric)


def load_runs(directory: Path) -> list[Run]:
    """Every run below ``directory`` with its config; [] if there is none (or no such directory).

    Incomplete last lines of runs still writing are skipped silently. A run without a readable
    config is an error: its condition cannot be told.
    """
    if not directory.is_dir() or not any(directory.rglob(METRICS_FILE)):
        return []
    runs = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        for run_dir in find_run_dirs([directory]):
            config = load_config(run_dir)
            if config is None:
                raise EvaluationError(f"{run_dir}: no readable {HYDRA_DIR}/{CONFIG_FILE}; cannot tell its condition")
            runs.append(Run(Path(run_dir), config))
    return runs


def group(runs: Sequence[Run], key: Callable[[Run], K]) -> dict[K, list[Run]]:
    """Runs by ``key``, each group in seed order (so groups of the same seeds line up)."""
    groups: dict[K, list[Run]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    for members in groups.values():
        members.sort(key=lambda r: r.seed)
    return groups


def per_seed(runs: Sequence[Run], fn: Callable[[Curve], float], metric: str = "team_return") -> dict[int, float]:
    """``{seed: fn(curve)}`` over runs, the form :func:`dqn_transfer.analysis.stats.difference` pairs by."""
    return {r.seed: float(fn(r.curve(metric))) for r in runs}
