"""Transfer metrics on learning curves: small pure functions, no files and no randomness.

A learning *curve* is a pair ``(steps, values)`` of 1-D arrays with strictly increasing steps.

The metrics are those of Taylor & Stone (2009), "Transfer Learning for Reinforcement Learning
Domains: A Survey", section 2.1: jumpstart, asymptotic performance, total reward (area under the
curve), transfer ratio and time to threshold. The statistics over seeds are in
:mod:`dqn_transfer.analysis.stats`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Curve = tuple[np.ndarray, np.ndarray]


def common_steps(curves: Sequence[Curve]) -> tuple[np.ndarray, np.ndarray]:
    """``(steps, values)``: the evaluation steps all runs share and each run's values there, ``[runs, steps]``."""
    common = curves[0][0]
    for steps, _ in curves[1:]:
        common = np.intersect1d(common, steps)
    if common.size == 0:
        raise ValueError("the runs share no evaluation step; cannot average their curves")
    return common, np.stack([v[np.isin(s, common)] for s, v in curves])


def mean_curve(curves: Sequence[Curve]) -> Curve:
    """Pointwise mean over runs, at the evaluation steps all runs share."""
    steps, values = common_steps(curves)
    return steps, values.mean(axis=0)


def check_curve(curve: Curve) -> Curve:
    """``curve`` as two float arrays; a ValueError unless they are non-empty, 1-D, of equal length, with
    strictly increasing steps."""
    steps, values = (np.asarray(a, dtype=np.float64) for a in curve)
    if steps.ndim != 1 or steps.shape != values.shape or steps.size == 0:
        raise ValueError("a curve is two non-empty 1-D arrays (steps, values) of equal length")
    if np.any(np.diff(steps) <= 0):
        raise ValueError("curve steps must be strictly increasing")
    return steps, values


def jumpstart(transfer_curve: Curve, baseline_curve: Curve) -> float:
    """Initial gain from transfer: transfer minus baseline value at their first common step."""
    (ts, tv), (bs, bv) = check_curve(transfer_curve), check_curve(baseline_curve)
    common = np.intersect1d(ts, bs)
    if common.size == 0:
        raise ValueError("the curves share no evaluation step; jumpstart is undefined")
    first = common[0]
    return float(tv[ts == first][0] - bv[bs == first][0])


def tail_count(size: int, tail_fraction: float) -> int:
    """How many evaluations the last ``tail_fraction`` of ``size`` holds: ``ceil(tail_fraction * size)``,
    at least one; a curve's tail in :func:`asymptotic_performance` and in the budget rule's slopes.

    :param size: the curve's number of evaluations.
    :param tail_fraction: the share of the evaluations, in (0, 1].
    """
    if not 0.0 < tail_fraction <= 1.0:
        raise ValueError(f"tail_fraction must be in (0, 1], got {tail_fraction}")
    return max(1, math.ceil(round(tail_fraction * size, 9)))  # round: 0.1 * 30 is 3.0000000000000004


def asymptotic_performance(curve: Curve, tail_fraction: float = 0.1) -> float:
    """Final performance: mean of the last ``ceil(tail_fraction * n)`` evaluations (at least one).

    Averaging a tail rather than taking the last point damps the noise of a single evaluation.
    """
    _, values = check_curve(curve)
    return float(values[-tail_count(values.size, tail_fraction) :].mean())


def total_reward(curve: Curve) -> float:
    """Area under the curve over steps (trapezoid rule); 0 for a single evaluation."""
    steps, values = check_curve(curve)
    return _area(steps, values)


def mean_over_training(curve: Curve) -> float:
    """Total reward divided by the steps it spans: the average evaluation value, in the metric's units.

    Unlike the area it does not grow with the run's length, so it reads like a return. A single
    evaluation is its own average.
    """
    steps, values = curve
    span = float(steps[-1] - steps[0])
    return total_reward(curve) / span if span > 0 else float(values[0])


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
    (ts, tv), (bs, bv) = check_curve(transfer_curve), check_curve(baseline_curve)
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
    steps, values = check_curve(curve)
    reached = np.flatnonzero(values >= threshold)
    return float(steps[reached[0]]) if reached.size else math.nan
