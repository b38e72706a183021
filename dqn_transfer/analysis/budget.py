"""Converged budgets (issue #24, the study's second edition): how many steps to train each cell, fixed in
advance from pilot runs.

The first edition ran every cell for the same 8,000 steps, and its largest teams were still learning at the
end, so a difference between conditions there mixed their effect with how far each had got. The second
edition gives each cell (a condition: the runs that differ only in map and seed) the budget its pilot runs
say it needs, by a rule written down before the runs:

1. **plateau slope** (:func:`plateau_slope`): the least-squares slope of a run's last 20% of evaluations;
   for a cell, the median over its runs of theirs (:func:`median_plateau_slope`);
2. **converged step** (:func:`converged_step`): the first evaluation step from which that median slope,
   computed on the curves cut at that step and at every later one, stays below a threshold;
3. **budget** (:func:`budget_rule`): ``min(cap, round_up(safety * converged step))``; a cell whose pilot
   never converged gets the cap, flagged, since the pilot cannot say how long it needs.

Slopes are in the curve's units per 1,000 steps (:data:`PER_STEPS`): with the study's score, a fraction of
the map's optimal return, a slope of 0.01 gains 1% of the optimum every 1,000 steps. Pure functions of
learning curves (:data:`~dqn_transfer.analysis.transfer_metrics.Curve`), no files and no randomness; which
runs form a cell of the study is :mod:`dqn_transfer.experiments.budgets`' business.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from dqn_transfer.analysis.transfer_metrics import Curve, check_curve, common_steps, tail_count

PER_STEPS = 1000  # slopes are per this many steps
FRACTION = 0.2  # the plateau slope is fitted to a curve's last 20% of evaluations ...
MIN_POINTS = 4  # ... and to at least 4 of them: the first edition's last 20% (17 evaluations, every 500 steps)
SAFETY = 1.5  # the budget is this multiple of the converged step ...
CAP = 32_000  # ... at most this many steps (4 x the first edition's budget) ...
ROUND_TO = 1_000  # ... rounded up to a multiple of this

Cell = TypeVar("Cell")


def _window(size: int, fraction: float, min_points: int) -> int:
    """How many of a curve's last ``size`` evaluations a plateau slope is fitted to."""
    if min_points < 2:
        raise ValueError(f"a slope needs at least 2 points, got min_points={min_points}")
    if size < min_points:
        raise ValueError(f"a plateau slope needs at least {min_points} evaluations, got {size}")
    return max(min_points, tail_count(size, fraction))


def plateau_slope(curve: Curve, fraction: float = FRACTION, min_points: int = MIN_POINTS) -> float:
    """The least-squares slope of a curve's last ``fraction`` of evaluations, in values per 1,000 steps.

    The line is fitted to the last ``max(min_points, ceil(fraction * n))`` of the curve's ``n`` evaluations
    (:func:`~dqn_transfer.analysis.transfer_metrics.tail_count`, the tail that final performance averages):
    a fifth of a long curve, never so few points that two noisy evaluations make the slope. A fitted line
    uses every evaluation of the window, where last-minus-first would rest on two. A straight line has
    exactly its slope.

    :param curve: ``(steps, values)``, steps strictly increasing.
    :param fraction: the share of the evaluations the line is fitted to, in (0, 1].
    :param min_points: the fewest evaluations the line is fitted to (at least 2); a curve with fewer is a
        ValueError.
    """
    steps, values = check_curve(curve)
    count = _window(steps.size, fraction, min_points)
    x = [float(step) / PER_STEPS for step in steps[-count:]]
    tail = [float(value) for value in values[-count:]]
    # Exactly rounded sums (math.fsum) of single products, not numpy's mean or `@`: BLAS kernels sum in
    # an order of their own (and fuse multiply-adds) that differs between CPUs, and a slope that moves in
    # its last bits moves a budget whose slope sits at the threshold. These are the same bits on any CPU.
    x_mean, tail_mean = math.fsum(x) / count, math.fsum(tail) / count
    centred = [value - x_mean for value in x]
    covariance = math.fsum(c * (value - tail_mean) for c, value in zip(centred, tail, strict=True))
    return covariance / math.fsum(c * c for c in centred)  # a flat tail: exactly 0


def median_plateau_slope(curves: Sequence[Curve], fraction: float = FRACTION, min_points: int = MIN_POINTS) -> float:
    """How fast a set of runs was still improving at their end: the median over runs of their
    :func:`plateau_slope` (for an even number of runs, the mean of the middle two).

    The median of the runs' slopes, not the slope of their median curve, for three reasons:

    - it is a run's slope. The pointwise median curve is made of different runs at different steps: where
      runs have levelled off at different heights and one is still climbing between them, the median curve
      follows that one run, and has its slope however many runs have stopped (two flat runs and one rising
      run: the median slope is 0, the median curve's slope is the rising run's; ``tests/test_budget.py``);
    - it reads as a count: below a threshold, about half the runs (at least half, for an odd number) improve
      more slowly than it;
    - one run jumping or collapsing late (a team finding its last chest, a DQN run diverging) moves it by
      at most the gap to the next run's slope, where it moves a mean (and the slope of the mean curve, which
      is the mean of the slopes) by its whole change over the number of runs.

    :param curves: the runs' ``(steps, values)``.
    :param fraction: as :func:`plateau_slope`'s.
    :param min_points: as :func:`plateau_slope`'s.
    """
    if not curves:
        raise ValueError("no runs' curves given")
    return float(np.median([plateau_slope(curve, fraction, min_points) for curve in curves]))


def slope_trajectory(curves: Sequence[Curve], fraction: float = FRACTION, min_points: int = MIN_POINTS) -> Curve:
    """``(steps, slopes)``: :func:`median_plateau_slope` of the runs' curves cut at each evaluation step
    they all share (:func:`~dqn_transfer.analysis.transfer_metrics.common_steps`), from the ``min_points``-th
    on: how fast the median run would have been improving at the end of a pilot stopped at that step.

    :param curves: the runs' ``(steps, values)``.
    :param fraction: as :func:`plateau_slope`'s.
    :param min_points: as :func:`plateau_slope`'s; the runs must share at least this many steps.
    """
    if not curves:
        raise ValueError("no runs' curves given")
    steps, values = common_steps(curves)  # [runs, steps]
    if steps.size < min_points:
        raise ValueError(f"the runs share {steps.size} evaluation steps; a plateau slope needs {min_points}")
    slopes = [
        median_plateau_slope([(steps[:end], run[:end]) for run in values], fraction, min_points)
        for end in range(min_points, steps.size + 1)
    ]
    return steps[min_points - 1 :], np.array(slopes)


def _check_threshold(threshold: float) -> None:
    if not (math.isfinite(threshold) and threshold > 0.0):
        raise ValueError(f"the threshold is a positive slope (values per {PER_STEPS:,} steps), got {threshold}")


def _converged(trajectory: Curve, threshold: float) -> int | None:
    """The first step of ``trajectory`` (:func:`slope_trajectory`) from which every slope is below
    ``threshold``; None if its last one is not (a ``nan`` slope is not below)."""
    steps, slopes = trajectory
    not_below = np.flatnonzero(~(slopes < threshold))
    first = int(not_below[-1]) + 1 if not_below.size else 0
    return int(steps[first]) if first < steps.size else None


def decision_margin(trajectory: Curve, threshold: float) -> float:
    """How close the converged-step decision on ``trajectory`` (:func:`slope_trajectory`) came to going the
    other way: the least ``|slope - threshold|`` over the slopes that decided it, the last one not below the
    threshold (which put the converged step after it) and every one after it (each of which had to stay
    below). A slope moving by less than this cannot move the converged step; a margin of 0 is a tie. Without
    a slope not below the threshold, every slope decided it."""
    steps, slopes = trajectory
    not_below = np.flatnonzero(~(slopes < threshold))
    deciding = slopes[int(not_below[-1]) if not_below.size else 0 :]
    return float(np.min(np.abs(deciding - threshold)))


def converged_step(
    curves: Sequence[Curve], threshold: float, fraction: float = FRACTION, min_points: int = MIN_POINTS
) -> int | None:
    """The step by which the median run has stopped improving: the smallest evaluation step ``S`` the runs
    share such that, for ``S`` and for every later shared step ``T``, :func:`median_plateau_slope` of the
    curves cut at ``T`` (their evaluations up to and including ``T``) is below ``threshold``. None when the
    slope of the whole curves is not below it: not converged within them.

    Candidates start at the ``min_points``-th shared step (the first with a slope). "Every later" matters:
    a curve is flat before learning starts (DQN before its first update, a team that has not found a chest)
    and a noisy plateau dips under any threshold now and then, so the first step below the threshold would
    be too early; the converged step is the start of the last stretch below it, which the curves' end cuts
    short. A falling curve counts as converged (it is not improving), which is what a budget asks.

    :param curves: the runs' ``(steps, values)``, e.g. one cell's pilot runs.
    :param threshold: the slope, in values per 1,000 steps (> 0), below which the median run has stopped
        improving.
    :param fraction: as :func:`plateau_slope`'s.
    :param min_points: as :func:`plateau_slope`'s.
    """
    _check_threshold(threshold)
    return _converged(slope_trajectory(curves, fraction, min_points), threshold)


@dataclass(frozen=True)
class Budget:
    """The budget rule on one cell's pilot runs (:func:`budget_rule`).

    ``budget`` is ``min(cap, round_up(safety * converged_step))``; when the runs had not converged by the
    pilot's end (``converged_step`` None) it is the cap, and ``capped`` is True: the pilot cannot tell how
    long the cell needs, so its budget is a ceiling, not a measurement.
    """

    converged_step: int | None  # None: not converged within the pilot
    budget: int
    capped: bool  # the cap set the budget: the rule asked for more, or the pilot did not converge
    slope_at_budget: float | None  # median plateau slope of the curves cut at the budget; None: beyond the pilot
    final_slope: float  # median plateau slope of the whole pilot curves
    pilot_steps: int  # the last evaluation step the pilot's runs share
    margin: float  # how close the decision came to the threshold (:func:`decision_margin`)

    @property
    def converged(self) -> bool:
        return self.converged_step is not None


def _round_up(value: float, multiple: int) -> int:
    return math.ceil(round(value / multiple, 9)) * multiple  # round: 1.1 * 3000 / 100 is 33.00000000000001


def budget_rule(
    curves: Sequence[Curve],
    threshold: float,
    safety: float = SAFETY,
    cap: int = CAP,
    round_to: int = ROUND_TO,
    fraction: float = FRACTION,
    min_points: int = MIN_POINTS,
) -> Budget:
    """A cell's budget from its pilot runs: ``min(cap, round_up(safety * S))``, ``S`` the
    :func:`converged_step`, rounded up to a multiple of ``round_to``; the cap when the pilot did not
    converge. The safety factor leaves room for the noise in ``S`` and for the slow last gains a threshold
    does not see; the cap bounds what the study can afford. The slope at the budget is that of the curves
    cut at their last shared evaluation at or before it (None when the budget lies beyond the pilot).

    :param curves: one cell's pilot runs, ``(steps, values)`` each, values in the units of ``threshold``.
    :param threshold: as :func:`converged_step`'s, in values per 1,000 steps.
    :param safety: the multiple of the converged step, at least 1.
    :param cap: the largest budget, in steps (> 0).
    :param round_to: the budget is rounded up to a multiple of this many steps (> 0).
    :param fraction: as :func:`plateau_slope`'s.
    :param min_points: as :func:`plateau_slope`'s.
    """
    _check_threshold(threshold)
    if not safety >= 1.0:
        raise ValueError(f"the safety factor is at least 1, got {safety}")
    if cap <= 0 or round_to <= 0:
        raise ValueError(f"the cap and the rounding are positive step counts, got {cap} and {round_to}")
    steps, slopes = slope_trajectory(curves, fraction, min_points)
    step = _converged((steps, slopes), threshold)
    wanted = None if step is None else _round_up(safety * step, round_to)
    budget = cap if wanted is None else min(cap, wanted)
    at = int(np.searchsorted(steps, budget, side="right")) - 1  # the last shared step at or before the budget
    return Budget(
        converged_step=step,
        budget=budget,
        capped=wanted is None or wanted > cap,
        slope_at_budget=float(slopes[at]) if at >= 0 and budget <= steps[-1] else None,
        final_slope=float(slopes[-1]),
        pilot_steps=int(steps[-1]),
        margin=decision_margin((steps, slopes), threshold),
    )


@dataclass(frozen=True)
class BudgetRule:
    """The rule's parameters, fixed in advance and the same for every cell (not tuned per cell); each
    as :func:`budget_rule`'s."""

    threshold: float
    safety: float = SAFETY
    cap: int = CAP
    round_to: int = ROUND_TO
    fraction: float = FRACTION
    min_points: int = MIN_POINTS


def budgets_per_cell(cells: Mapping[Cell, Sequence[Curve]], rule: BudgetRule) -> dict[Cell, Budget]:
    """:func:`budget_rule` applied to each cell's pilot runs, by one ``rule``.

    :param cells: each cell's pilot runs' curves, by cell.
    :param rule: the rule's parameters.
    """
    return {cell: budget_rule(curves, **dataclasses.asdict(rule)) for cell, curves in cells.items()}
