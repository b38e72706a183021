"""Runs to numbers: what a run is (learner, mode, team size), its scores, and how runs are paired and compared.

A run's **score** is its mean greedy-evaluation team return over training as a fraction of its map's optimal
team return where the map has one, so maps of different sizes share a scale. Runs of two conditions with the
same (map seed, seed) share their map, initial values and exploration noise: differences are paired by that unit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import scipy.stats

from dqn_transfer.analysis.stats import Estimate, improvement_probability
from dqn_transfer.analysis.transfer_metrics import asymptotic_performance, mean_over_training
from dqn_transfer.enums import Algorithm
from dqn_transfer.experiments.raw_data import RunData

PRIMARY_LEARNER = Algorithm.sarsa.value  # the study's own learner; Double DQN is run beside it, exploratory
FINAL_TAIL = 0.2  # final performance: the mean of the last 20% of a run's evaluations
SLOPE_RESAMPLES = 10_000


def learner(run: RunData) -> str:
    return run.config["agent"]["algorithm"]


def mode(run: RunData) -> str:
    return run.config["env"]["mode"]


def team_size(run: RunData) -> int:
    return int(run.config["env"]["num_agents"])


def learners(runs: Sequence[RunData]) -> list[str]:
    """The learners present, the primary one first."""
    return sorted({learner(r) for r in runs}, key=lambda a: (a != PRIMARY_LEARNER, a))


def score(run: RunData) -> float:
    return mean_over_training(run.score_curve())


def raw_score(run: RunData) -> float:
    """Mean evaluation team return over training, in return units."""
    return mean_over_training(run.curve())


def final_score(run: RunData, budget: int | None = None) -> float:
    """The mean score of the last 20% of the run's evaluations at or before ``budget`` (None: all)."""
    steps, values = run.score_curve()
    kept = steps <= (math.inf if budget is None else budget)
    return asymptotic_performance((steps[kept], values[kept]), FINAL_TAIL)


def on_total_steps(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The score curve against total env steps: a warm-started run's starts after the steps spent on what it
    started from (its source's pretraining, a curriculum's stages)."""
    steps, values = run.score_curve()
    return steps + run.steps_before, values


def group(runs: Sequence[RunData], key: Callable[[RunData], Any]) -> dict[Any, list[RunData]]:
    """Runs by ``key``, each group in unit order (so groups of the same units line up)."""
    groups: dict[Any, list[RunData]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    return {k: sorted(v, key=lambda r: r.unit) for k, v in groups.items()}


def paired(a: Sequence[RunData], b: Sequence[RunData], fn: Callable[[RunData], float]) -> np.ndarray:
    """``fn(a) - fn(b)`` for every unit both conditions ran."""
    by_unit = {r.unit: fn(r) for r in b}
    return np.array([fn(r) - by_unit[r.unit] for r in a if r.unit in by_unit])


def by_map(runs: Sequence[RunData], fn: Callable[[RunData], float]) -> np.ndarray:
    """``[runs per map, maps]``, the layout rliable stratifies by; one column when the maps hold unequal
    numbers of runs."""
    maps = group(runs, lambda r: r.map_seed)
    counts = {len(v) for v in maps.values()}
    if len(counts) != 1:
        return np.array([[fn(r)] for r in runs])
    return np.array([[fn(r) for r in maps[m]] for m in sorted(maps)]).T


def improvement(
    a: Sequence[RunData], b: Sequence[RunData], fn: Callable[[RunData], float], rng: np.random.Generator
) -> Estimate:
    """P(a run of ``a`` scores higher than a run of ``b`` on the same map), rliable's, stratified by map;
    over the maps both conditions ran, so that the two score tables' columns are the same maps."""
    shared = {r.map_seed for r in a} & {r.map_seed for r in b}
    a, b = ([r for r in runs if r.map_seed in shared] for runs in (a, b))
    return improvement_probability(by_map(a, fn), by_map(b, fn), rng)


def slope(diffs: dict[int, np.ndarray], rng: np.random.Generator) -> tuple[float, Estimate, Estimate]:
    """``(slope, bootstrap, t)`` of a paired difference against team size m: the least-squares slope of
    the per-m mean differences, with a percentile interval resampling the units within each m, and the
    classic t interval of the regression of every unit's difference on m."""
    sizes = np.array(sorted(diffs), dtype=np.float64)
    means = np.array([diffs[int(m)].mean() for m in sizes])
    centred = sizes - sizes.mean()
    point = float(centred @ means / (centred @ centred))
    resampled = np.stack(
        [
            d[rng.integers(0, d.size, size=(SLOPE_RESAMPLES, d.size))].mean(axis=1)
            for d in (diffs[int(m)] for m in sizes)
        ],
        axis=1,
    )  # [resamples, sizes]
    slopes = (resampled - resampled.mean(axis=1, keepdims=True)) @ centred / (centred @ centred)
    low, high = np.quantile(slopes, [0.025, 0.975])
    x = np.concatenate([np.full(diffs[int(m)].size, m) for m in sizes])
    y = np.concatenate([diffs[int(m)] for m in sizes])
    fit = scipy.stats.linregress(x, y)
    half = scipy.stats.t.ppf(0.975, x.size - 2) * fit.stderr
    n = int(x.size)
    return (
        point,
        Estimate(point, float(low), float(high), n),
        Estimate(float(fit.slope), fit.slope - half, fit.slope + half, n),
    )
