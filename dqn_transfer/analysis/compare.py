"""Transfer runs against baseline runs: every transfer metric with a bootstrap CI over seeds.

The per-run metrics are those of :mod:`dqn_transfer.analysis.transfer_metrics`; the intervals are
:func:`dqn_transfer.analysis.stats.estimate`'s.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from dqn_transfer.analysis.runs import find_run_dirs, learning_curve, run_seed
from dqn_transfer.analysis.stats import estimate, improvement_probability, iqm
from dqn_transfer.analysis.transfer_metrics import (
    Curve,
    asymptotic_performance,
    jumpstart,
    mean_curve,
    time_to_threshold,
    total_reward,
    transfer_ratio,
)


def _seed_order(run_dirs: Sequence[Path]) -> list[int]:
    """Indices of the runs sorted by seed; the given order if some run does not record its seed."""
    seeds = [run_seed(d) for d in run_dirs]
    known = [seed for seed in seeds if seed is not None]
    if len(known) != len(seeds):
        return list(range(len(run_dirs)))
    return sorted(range(len(run_dirs)), key=known.__getitem__)


def _pair_by_seed(transfer_dirs: Sequence[Path], baseline_dirs: Sequence[Path]) -> list[tuple[int, int]]:
    """Index pairs (transfer, baseline): the k-th transfer run by seed with the k-th baseline run.

    With the same seeds in both conditions (the usual sweep), runs of equal seed are paired, so
    the difference of a per-run metric cancels what a seed shares between them (map, initial
    weights, exploration noise). Unequal counts pair up to the shorter list, with a warning.
    """
    if len(transfer_dirs) != len(baseline_dirs):
        warnings.warn(
            f"{len(transfer_dirs)} transfer vs {len(baseline_dirs)} baseline runs: "
            f"differences use the first {min(len(transfer_dirs), len(baseline_dirs))} "
            "pairs in seed order",
            stacklevel=3,
        )
    return list(zip(_seed_order(transfer_dirs), _seed_order(baseline_dirs)))


def _sooner_is_higher(times: Sequence[float]) -> list[float]:
    """Times to a threshold as scores where higher is better: minus the time, -inf for never (nan)."""
    return [-math.inf if math.isnan(t) else -t for t in times]


def _within(curve: Curve, start: float, end: float) -> Curve:
    steps, values = curve
    kept = (steps >= start) & (steps <= end)
    if not kept.any():
        raise ValueError(f"the runs share no span of evaluation steps (from {start:g} to {end:g})")
    return steps[kept], values[kept]


def compare_runs(
    transfer_dirs: Sequence[str | os.PathLike],
    baseline_dirs: Sequence[str | os.PathLike],
    metric: str = "team_return",
    threshold: float | None = None,
    seed: int = 0,
    transfer_offset: int = 0,
) -> dict[str, dict[str, float]]:
    """Each transfer metric as ``{"mean", "low", "high", "n"}`` with a 95% bootstrap CI over seeds.

    - ``jumpstart``: paired by seed (see :func:`_pair_by_seed`), each transfer run against the
      baseline run of its seed at their first common step: at step 0 a seed's two runs share their map
      and initial exploration, so the pair's difference is the transfer alone;
    - ``transfer_ratio``: each transfer run against the *mean* baseline curve (the ratio of one run's
      area to another's would carry the baseline run's noise twice);
    - ``asymptotic_performance``, ``total_reward`` (over the span of steps every run covers) and
      (given ``threshold``) ``time_to_threshold``:
      per condition (``/transfer``, ``/baseline``) and as paired differences transfer - baseline
      (``/difference``, see :func:`_pair_by_seed`); a negative time difference means transfer
      reached the threshold sooner.
    ``transfer_offset``: the env steps the transfer runs spent before their own step 0 (a source's
    pretraining, a curriculum's earlier stages). Their curves are shifted by it, so the two conditions
    are compared at equal *total* steps: jumpstart at the transfer runs' first evaluation, areas over
    the steps all runs cover, time to threshold in total steps, and asymptotic performance at the end
    of each (equal budgets when the baseline ran ``offset`` steps longer).
    Non-finite per-run values (a run that never reaches the threshold, an infinite ratio) are left
    out of these means, so ``n`` says how many runs each row rests on. Beside them, with every run:
    each condition's IQM of final performance (``/transfer_iqm``, ``/baseline_iqm``), the probability
    that a transfer run ends above a baseline run (``/P(transfer > baseline)``) and, given a threshold,
    that it gets there sooner (``time_to_threshold/P(transfer sooner)``, a run that never does counted
    as slower than every run that did), each with rliable's bootstrap interval. The directories are those of
    :func:`~dqn_transfer.analysis.runs.find_run_dirs`: unusable ones are skipped with a warning.
    """
    t_dirs = find_run_dirs(transfer_dirs, kind="transfer run")
    b_dirs = find_run_dirs(baseline_dirs, kind="baseline run")
    if transfer_offset < 0:
        raise ValueError(f"the transfer offset counts steps spent before the runs: >= 0, got {transfer_offset}")
    t_curves = [(steps + transfer_offset, values) for steps, values in (learning_curve(d, metric) for d in t_dirs)]
    b_curves = [learning_curve(d, metric) for d in b_dirs]
    b_mean = mean_curve(b_curves)
    pairs = _pair_by_seed(t_dirs, b_dirs)

    per_run: dict[str, list[float]] = {
        "jumpstart": [jumpstart(t_curves[i], b_curves[j]) for i, j in pairs],
        "transfer_ratio": [transfer_ratio(c, b_mean) for c in t_curves],
    }
    # Areas over the steps every run covers: with an offset the transfer runs start later, and an area
    # over a longer span is not comparable.
    start, end = max(c[0][0] for c in t_curves + b_curves), min(c[0][-1] for c in t_curves + b_curves)
    per_curve_metrics: dict[str, Callable[[Curve], float]] = {
        "asymptotic_performance": asymptotic_performance,
        "total_reward": lambda c: total_reward(_within(c, start, end)),
    }
    if threshold is not None:
        per_curve_metrics["time_to_threshold"] = lambda c: time_to_threshold(c, threshold)
    for name, fn in per_curve_metrics.items():
        t_values, b_values = [fn(c) for c in t_curves], [fn(c) for c in b_curves]
        per_run[f"{name}/transfer"] = t_values
        per_run[f"{name}/baseline"] = b_values
        per_run[f"{name}/difference"] = [t_values[i] - b_values[j] for i, j in pairs]

    rng = np.random.default_rng(seed)
    results = {name: asdict(estimate(values, rng)) for name, values in per_run.items()}
    # The field's robust view of the same runs: the IQM of each condition's final performance, and the
    # probability that a transfer run beats a baseline run (rliable, stratified bootstrap).
    final_t, final_b = per_run["asymptotic_performance/transfer"], per_run["asymptotic_performance/baseline"]
    results["asymptotic_performance/transfer_iqm"] = asdict(iqm(final_t, rng))
    results["asymptotic_performance/baseline_iqm"] = asdict(iqm(final_b, rng))
    results["asymptotic_performance/P(transfer > baseline)"] = asdict(improvement_probability(final_t, final_b, rng))
    if threshold is not None:  # every run counts: one that never reached the threshold is slower than any that did
        sooner_t, sooner_b = (
            _sooner_is_higher(per_run[f"time_to_threshold/{side}"]) for side in ("transfer", "baseline")
        )
        results["time_to_threshold/P(transfer sooner)"] = asdict(improvement_probability(sooner_t, sooner_b, rng))
    return results


def format_table(results: dict[str, dict[str, float]]) -> str:
    """Markdown table of :func:`compare_runs` results (``n/a`` where a value is undefined; ``no spread``
    where every resample gave the same value, e.g. every paired difference is equal: a zero-width
    interval is not a measured certainty)."""

    def fmt(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{x:.4g}"

    lines = ["| metric | mean | 95% CI | n |", "|---|---:|---:|---:|"]
    for name, r in results.items():
        if not (math.isfinite(r["low"]) and math.isfinite(r["high"])):
            ci = "n/a"
        else:
            ci = "no spread" if r["low"] == r["high"] else f"[{fmt(r['low'])}, {fmt(r['high'])}]"
        lines.append(f"| {name} | {fmt(r['mean'])} | {ci} | {r['n']} |")
    return "\n".join(lines)
