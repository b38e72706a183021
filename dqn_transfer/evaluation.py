"""Transfer metrics with bootstrap confidence intervals, computed from run directories.

Evaluation reads what the trainer wrote (``run_dir/metrics.jsonl``, one greedy evaluation per line:
``{"step", "team_return", "success_rate", ...}``), never live objects, so it works on runs from
any machine or SLURM job. A learning *curve* is a pair ``(steps, values)`` of 1-D arrays with
strictly increasing steps.

The metrics are those of Taylor & Stone (2009), "Transfer Learning for Reinforcement Learning
Domains: A Survey", section 2.1: jumpstart, asymptotic performance, total reward (area under the
curve), transfer ratio and time to threshold. Each is a small pure function of curves; the
statistics over seeds (a percentile bootstrap) are in :func:`bootstrap_ci` and :func:`compare_runs`.

Command line (the shell expands globs)::

    python -m dqn_transfer.evaluation --transfer outputs/tr/* --baseline outputs/base/* [--threshold X]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

Curve = tuple[np.ndarray, np.ndarray]
METRICS_FILE = "metrics.jsonl"


class EvaluationError(Exception):
    """A run directory or its metrics cannot be used; the message is one user-facing line."""


# ---------------------------------------------------------------------------------------------
# Reading run directories


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, Any]]:
    """All evaluation records of a run, in file order.

    A last line without its newline that does not parse is a write cut short by a killed run: it
    is skipped with a warning. Any other bad line is an error.
    """
    path = Path(run_dir) / METRICS_FILE
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
        raise EvaluationError(f"{Path(run_dir) / METRICS_FILE}: no {metric!r} evaluations "
                              f"(available: {', '.join(available) or 'none'})")
    steps = np.array(sorted(by_step), dtype=np.float64)
    return steps, np.array([by_step[int(s)] for s in steps], dtype=np.float64)


def mean_curve(curves: Sequence[Curve]) -> Curve:
    """Pointwise mean over runs, at the evaluation steps all runs share."""
    common = curves[0][0]
    for steps, _ in curves[1:]:
        common = np.intersect1d(common, steps)
    if common.size == 0:
        raise ValueError("the runs share no evaluation step; cannot average their curves")
    values = [v[np.isin(s, common)] for s, v in curves]
    return common, np.mean(values, axis=0)


# ---------------------------------------------------------------------------------------------
# Transfer metrics (Taylor & Stone 2009) on curves


def _check_curve(curve: Curve) -> Curve:
    steps, values = (np.asarray(a, dtype=np.float64) for a in curve)
    if steps.ndim != 1 or steps.shape != values.shape or steps.size == 0:
        raise ValueError("a curve is two non-empty 1-D arrays (steps, values) of equal length")
    if np.any(np.diff(steps) <= 0):
        raise ValueError("curve steps must be strictly increasing")
    return steps, values


def jumpstart(transfer_curve: Curve, baseline_curve: Curve) -> float:
    """Initial gain from transfer: transfer minus baseline value at their first common step."""
    (ts, tv), (bs, bv) = _check_curve(transfer_curve), _check_curve(baseline_curve)
    common = np.intersect1d(ts, bs)
    if common.size == 0:
        raise ValueError("the curves share no evaluation step; jumpstart is undefined")
    first = common[0]
    return float(tv[ts == first][0] - bv[bs == first][0])


def asymptotic_performance(curve: Curve, tail_fraction: float = 0.1) -> float:
    """Final performance: mean of the last ``ceil(tail_fraction * n)`` evaluations (at least one).

    Averaging a tail rather than taking the last point damps the noise of a single evaluation.
    """
    _, values = _check_curve(curve)
    if not 0.0 < tail_fraction <= 1.0:
        raise ValueError(f"tail_fraction must be in (0, 1], got {tail_fraction}")
    count = max(1, math.ceil(round(tail_fraction * values.size, 9)))  # round: 0.1 * 30 is 3.0000000000000004
    return float(values[-count:].mean())


def total_reward(curve: Curve) -> float:
    """Area under the curve over steps (trapezoid rule); 0 for a single evaluation."""
    steps, values = _check_curve(curve)
    return _area(steps, values)


def transfer_ratio(transfer_curve: Curve, baseline_curve: Curve) -> float:
    """Relative gain in area under the curve: ``(A_transfer - A_baseline) / A_baseline``.

    Taylor & Stone's ratio assumes positive areas, but returns here are mostly negative (step
    costs), where the plain ratio flips sign or explodes. So both areas are measured *above the
    common floor*, the lowest value either curve reaches, over the steps both curves cover
    (``[max(first steps), min(last steps)]``, each curve linearly interpolated at the union of their
    steps). Consequences, by design:

    - both areas are >= 0, the ratio is 0 for identical curves, > 0 when transfer is better;
    - it is invariant to shifting or scaling all returns (e.g. changing the step cost offset);
    - ``inf`` when the baseline sits at the floor throughout (area 0) and transfer does not,
      ``nan`` when both are flat at the same value (0 / 0), or when the curves do not overlap.
    The floor is data-dependent, so compare ratios only between curves of the same experiment.
    """
    (ts, tv), (bs, bv) = _check_curve(transfer_curve), _check_curve(baseline_curve)
    start, end = max(ts[0], bs[0]), min(ts[-1], bs[-1])
    if end <= start:
        return math.nan
    steps = np.union1d(ts, bs)
    steps = steps[(steps >= start) & (steps <= end)]
    t_values, b_values = np.interp(steps, ts, tv), np.interp(steps, bs, bv)
    floor = min(t_values.min(), b_values.min())
    t_area, b_area = _area(steps, t_values - floor), _area(steps, b_values - floor)
    if b_area == 0.0:
        return math.inf if t_area > 0.0 else math.nan
    return (t_area - b_area) / b_area


def _area(steps: np.ndarray, values: np.ndarray) -> float:
    """Trapezoid rule (``np.trapezoid`` is numpy >= 2 only)."""
    return float(np.sum(np.diff(steps) * (values[1:] + values[:-1]) / 2.0))


def time_to_threshold(curve: Curve, threshold: float) -> float:
    """First evaluation step whose value is >= ``threshold``; ``nan`` if the curve never gets there."""
    steps, values = _check_curve(curve)
    reached = np.flatnonzero(values >= threshold)
    return float(steps[reached[0]]) if reached.size else math.nan


# ---------------------------------------------------------------------------------------------
# Statistics over seeds


def bootstrap_ci(values: Sequence[float] | np.ndarray, rng: np.random.Generator,
                 n_resamples: int = 10000, confidence: float = 0.95) -> tuple[float, float, float]:
    """``(mean, low, high)``: percentile-bootstrap interval of the mean over seeds.

    Resamples the seeds with replacement ``n_resamples`` times and takes the ``(1 - confidence)/2``
    and ``(1 + confidence)/2`` quantiles of the resampled means. With a single value there is no
    spread to resample, so the interval is ``(nan, nan)`` rather than a falsely certain ``(v, v)``.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1 or values.size == 0:
        raise ValueError("bootstrap_ci needs a non-empty 1-D sequence of values")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    mean = float(values.mean())
    if values.size == 1:
        return mean, math.nan, math.nan
    indices = rng.integers(0, values.size, size=(n_resamples, values.size))
    means = values[indices].mean(axis=1)
    low, high = np.quantile(means, [(1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0])
    return mean, float(low), float(high)


def _run_seed(run_dir: Path) -> int | None:
    """The run's ``seed`` from its Hydra config (``.hydra/config.yaml``), if readable."""
    try:
        config = yaml.safe_load((run_dir / ".hydra" / "config.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return None
    seed = config.get("seed") if isinstance(config, dict) else None
    return seed if isinstance(seed, int) else None


def _seed_order(run_dirs: Sequence[Path]) -> list[int]:
    """Indices of the runs sorted by seed; the given order if some run does not record its seed."""
    seeds = [_run_seed(d) for d in run_dirs]
    if None in seeds:
        return list(range(len(run_dirs)))
    return sorted(range(len(run_dirs)), key=lambda i: seeds[i])


def _pair_by_seed(transfer_dirs: Sequence[Path], baseline_dirs: Sequence[Path]) -> list[tuple[int, int]]:
    """Index pairs (transfer, baseline): the k-th transfer run by seed with the k-th baseline run.

    With the same seeds in both conditions (the usual sweep), runs of equal seed are paired, so
    the difference of a per-run metric cancels what a seed shares between them (map, initial
    weights, exploration noise). Unequal counts pair up to the shorter list, with a warning.
    """
    if len(transfer_dirs) != len(baseline_dirs):
        warnings.warn(f"{len(transfer_dirs)} transfer vs {len(baseline_dirs)} baseline runs: "
                      f"differences use the first {min(len(transfer_dirs), len(baseline_dirs))} "
                      "pairs in seed order", stacklevel=3)
    return list(zip(_seed_order(transfer_dirs), _seed_order(baseline_dirs)))


def compare_runs(transfer_dirs: Sequence[str | os.PathLike], baseline_dirs: Sequence[str | os.PathLike],
                 metric: str = "team_return", threshold: float | None = None,
                 seed: int = 0) -> dict[str, dict[str, float]]:
    """Each transfer metric as ``{"mean", "low", "high", "n"}`` with a 95% bootstrap CI over seeds.

    - ``jumpstart`` and ``transfer_ratio``: each transfer run against the *mean* baseline curve
      (a per-run baseline would add the baseline's seed noise to every value);
    - ``asymptotic_performance``, ``total_reward`` and (given ``threshold``) ``time_to_threshold``:
      per condition (``/transfer``, ``/baseline``) and as paired differences transfer - baseline
      (``/difference``, see :func:`_pair_by_seed`); a negative time difference means transfer
      reached the threshold sooner.
    Non-finite per-run values (a run that never reaches the threshold, an infinite ratio) are left
    out of the statistics, so ``n`` says how many runs each row rests on.
    """
    t_dirs, b_dirs = [Path(d) for d in transfer_dirs], [Path(d) for d in baseline_dirs]
    if not t_dirs or not b_dirs:
        raise EvaluationError("need at least one transfer and one baseline run directory")
    t_curves = [learning_curve(d, metric) for d in t_dirs]
    b_curves = [learning_curve(d, metric) for d in b_dirs]
    b_mean = mean_curve(b_curves)
    pairs = _pair_by_seed(t_dirs, b_dirs)

    per_run: dict[str, list[float]] = {
        "jumpstart": [jumpstart(c, b_mean) for c in t_curves],
        "transfer_ratio": [transfer_ratio(c, b_mean) for c in t_curves],
    }
    per_curve_metrics = {"asymptotic_performance": asymptotic_performance, "total_reward": total_reward}
    if threshold is not None:
        per_curve_metrics["time_to_threshold"] = lambda c: time_to_threshold(c, threshold)
    for name, fn in per_curve_metrics.items():
        t_values, b_values = [fn(c) for c in t_curves], [fn(c) for c in b_curves]
        per_run[f"{name}/transfer"] = t_values
        per_run[f"{name}/baseline"] = b_values
        per_run[f"{name}/difference"] = [t_values[i] - b_values[j] for i, j in pairs]

    rng = np.random.default_rng(seed)
    results = {}
    for name, values in per_run.items():
        finite = np.asarray(values, dtype=np.float64)
        finite = finite[np.isfinite(finite)]
        mean, low, high = bootstrap_ci(finite, rng) if finite.size else (math.nan, math.nan, math.nan)
        results[name] = {"mean": mean, "low": low, "high": high, "n": int(finite.size)}
    return results


def format_table(results: dict[str, dict[str, float]]) -> str:
    """Markdown table of :func:`compare_runs` results (``n/a`` where a value is undefined)."""
    def fmt(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{x:.4g}"

    lines = ["| metric | mean | 95% CI | n |", "|---|---:|---:|---:|"]
    for name, r in results.items():
        ci = "n/a" if not (math.isfinite(r["low"]) and math.isfinite(r["high"])) \
            else f"[{fmt(r['low'])}, {fmt(r['high'])}]"
        lines.append(f"| {name} | {fmt(r['mean'])} | {ci} | {r['n']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the transfer-vs-baseline Markdown table; exit 1 with one ``error:`` line on bad input."""
    parser = argparse.ArgumentParser(prog="python -m dqn_transfer.evaluation",
                                     description="Transfer metrics (Taylor & Stone 2009) with "
                                                 "bootstrap 95% CIs over seeds.")
    parser.add_argument("--transfer", nargs="+", required=True, metavar="DIR", help="transfer run dirs")
    parser.add_argument("--baseline", nargs="+", required=True, metavar="DIR", help="baseline run dirs")
    parser.add_argument("--metric", default="team_return", help="metrics.jsonl key (default: team_return)")
    parser.add_argument("--threshold", type=float, default=None, help="value for time_to_threshold")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap RNG seed")
    args = parser.parse_args(argv)
    try:
        results = compare_runs(args.transfer, args.baseline, args.metric, args.threshold, args.seed)
    except (EvaluationError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(format_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
