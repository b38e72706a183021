"""Runs for other tools: run directories and the study's raw data in marl-eval's JSON layout
(:mod:`dqn_transfer.analysis.marl_eval` says what each level is).

Each run's metrics are the evaluation means the study keeps (:data:`~dqn_transfer.experiments.raw_data.METRICS`:
team return, success rate, trap rate, ...) and ``score``, the team return as a fraction of its map's
optimal team return (the study's score; absent where the map has no clean optimum). ``metrics.jsonl``
records no per-agent returns, so none are exported.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dqn_transfer.analysis.marl_eval import ENVIRONMENT, EvaluatedRun, marl_eval_tree
from dqn_transfer.analysis.runs import EvaluationError, find_run_dirs, load_config
from dqn_transfer.experiments.raw_data import RunData, read_data, run_data
from dqn_transfer.experiments.scoring import FINAL_TAIL

SCORE = "score"


def evaluated(run: RunData) -> EvaluatedRun:
    """A run of the study's data (or a run directory read as one), with its ``score`` beside its metrics."""
    metrics = dict(run.metrics)
    if run.optimal_return and "team_return" in metrics:
        metrics[SCORE] = tuple(float(v) for v in run.score_curve()[1])
    return EvaluatedRun(f"{run.experiment}/{run.name}" if run.experiment else run.name, run.config, run.steps, metrics)


def run_dirs_tree(
    paths: Sequence[str | os.PathLike], environment: str = ENVIRONMENT, final_tail: float = FINAL_TAIL
) -> dict[str, Any]:
    """marl-eval's dictionary of the runs at or below ``paths`` (see
    :func:`~dqn_transfer.analysis.runs.find_run_dirs`; unusable directories are skipped with a warning)."""
    runs = []
    for run_dir in find_run_dirs(paths):
        config = load_config(run_dir)
        if config is None or not isinstance(config.get("env"), dict):
            raise EvaluationError(f"{run_dir}: no readable .hydra/config.yaml (cannot tell its task and algorithm)")
        runs.append(evaluated(run_data(run_dir, config, "", str(run_dir))))
    return marl_eval_tree(runs, final_tail, environment)


def data_tree(files: Sequence[Path], final_tail: float = FINAL_TAIL) -> dict[str, Any]:
    """marl-eval's dictionary of the study's raw data files (``results/data/<experiment>.jsonl``): one
    environment per experiment, ``treasurehunt_<experiment>``, since marl-eval compares the algorithms of
    an environment over all its tasks and the experiments ask different questions."""
    tree: dict[str, Any] = {}
    for path in files:
        runs = read_data(path)
        if not runs:
            raise EvaluationError(f"{path}: no runs")
        environment = f"{ENVIRONMENT}_{runs[0].experiment}"
        if environment.lower() in tree:
            raise EvaluationError(f"{path}: experiment {runs[0].experiment!r} given twice")
        tree.update(marl_eval_tree([evaluated(r) for r in runs], final_tail, environment))
    return tree
