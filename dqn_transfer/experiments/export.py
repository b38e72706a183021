"""Runs for other tools: run directories and the study's raw data in marl-eval's JSON layout
(:mod:`dqn_transfer.analysis.marl_eval` says what each level is), with ``score`` beside each run's metrics.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from dqn_transfer.analysis.marl_eval import (
    ENVIRONMENT,
    EvaluatedRun,
    agent_return_metric,
    game_name,
    marl_eval_tree,
)
from dqn_transfer.analysis.runs import EvaluationError, find_run_dirs, load_config, read_metrics
from dqn_transfer.experiments.raw_data import RunData, latest_by_step, read_data, run_data
from dqn_transfer.experiments.scoring import FINAL_TAIL

SCORE = "score"


def evaluated(run: RunData) -> EvaluatedRun:
    """A run of the study's data (or a run directory read as one), with its ``score`` beside its metrics."""
    metrics = dict(run.metrics)
    if run.optimal_return and "team_return" in metrics:
        metrics[SCORE] = tuple(float(v) for v in run.score_curve()[1])
    return EvaluatedRun(f"{run.experiment}/{run.name}" if run.experiment else run.name, run.config, run.steps, metrics)


def agent_returns(run_dir: Path, steps: Sequence[int]) -> dict[str, tuple[float, ...]]:
    """``{agent_<i>_return: (its mean greedy return at each of steps)}`` for each agent of a run
    directory, from ``metrics.jsonl``'s ``agent_returns`` (a step evaluated twice keeps its later record);
    ``{}`` unless every one of those records has them, for the same number of agents.

    :param run_dir: the run directory.
    :param steps: the evaluation steps the run is exported with.
    """
    latest = latest_by_step(read_metrics(run_dir, warn_incomplete=False))
    per_step: list[list[Any]] = [latest[step].get("agent_returns") or [] for step in steps]
    if not per_step or not all(per_step) or len({len(values) for values in per_step}) > 1:
        return {}
    return {agent_return_metric(i): tuple(float(values[i]) for values in per_step) for i in range(len(per_step[0]))}


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
        data = run_data(run_dir, config, "", str(run_dir))
        run = evaluated(data)
        runs.append(replace(run, metrics={**run.metrics, **agent_returns(run_dir, data.steps)}))
    return marl_eval_tree(runs, final_tail, environment)


def data_tree(files: Sequence[Path], final_tail: float = FINAL_TAIL) -> dict[str, Any]:
    """marl-eval's dictionary of the study's raw data files (``results/v2/data/<experiment>.jsonl``): one
    environment per experiment, ``<game>_<experiment>`` (``treasurehunt_hypothesis``, ``lbf_lbf_hypothesis``),
    since marl-eval compares the algorithms of an environment over all its tasks and the experiments ask
    different questions."""
    tree: dict[str, Any] = {}
    for path in files:
        runs = read_data(path)
        if not runs:
            raise EvaluationError(f"{path}: no runs")
        environment = f"{game_name(runs[0].config)}_{runs[0].experiment}"
        if environment.lower() in tree:
            raise EvaluationError(f"{path}: experiment {runs[0].experiment!r} given twice")
        tree.update(marl_eval_tree([evaluated(r) for r in runs], final_tail, environment))
    return tree
