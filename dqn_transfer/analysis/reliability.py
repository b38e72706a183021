"""Whether runs learn, judged over seeds: solved runs, whether they stay solved, and two engines compared.

The rules, fixed before the runs they judge (docs/learning.md):

- an evaluation **solves** the task when its ``metric`` is at least ``at_least`` (the treasure hunt:
  ``success_rate`` 1.0, every chest taken in every greedy episode) — a :class:`Criterion`;
- a run **is solved** when most of its last :data:`LAST` evaluations solve the task (3 of 5): one
  evaluation's luck neither makes nor breaks it, where a run's last evaluation alone would;
- a run that solved the task at some evaluation **stays solved** as the share of its evaluations from then on
  that solve it, and **lost it** when it is not solved by the rule above;
- the **area under the curve** is the mean of the run's ``metric`` over its evaluations (equally spaced, the
  first at step 0): how soon and how much it learned, in the metric's units;
- two engines (or any two conditions) are compared per task (map) by the probability that a run of one
  scores higher than a run of the other, P(B > A), with rliable's stratified bootstrap 95% interval
  (:func:`~dqn_transfer.analysis.stats.improvement_probability`), on the area under the curve and on the
  final score, and by Fisher's exact test on the counts of solved runs. They **learn alike** when both
  intervals hold 0.5 and Fisher's p is at least 0.05. Not rejecting is not proving equal: the intervals'
  ends say how large a difference the runs leave possible.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.stats

from dqn_transfer.analysis.stats import Estimate, improvement_probability

LAST = 5  # a run is judged on its last 5 evaluations ...
MAJORITY = 3  # ... and is solved when at least 3 of them solve the task
ALPHA = 0.05  # Fisher's exact test on the solved counts: p below this is a difference


@dataclass(frozen=True)
class Criterion:
    """An evaluation solves the task when its ``metric`` is at least ``at_least``."""

    metric: str
    at_least: float


@dataclass(frozen=True)
class RunOutcome:
    """One run's learning, by the rules of this module."""

    solved: bool  # most of its last LAST evaluations solve the task
    first_solved: int | None  # the step of its first evaluation that solves it; None: never
    kept: float | None  # share of its evaluations from first_solved on that solve it; None: never solved
    auc: float  # mean of the metric over its evaluations
    final: float  # mean of the metric over its last LAST evaluations

    @property
    def lost(self) -> bool:
        """Solved the task at some evaluation, and is not solved at the end."""
        return self.first_solved is not None and not self.solved


def run_outcome(steps: Sequence[int], values: Sequence[float] | np.ndarray, at_least: float) -> RunOutcome:
    """A run's :class:`RunOutcome` from its evaluation ``steps`` and its metric's ``values`` there.

    :param steps: the evaluation steps, increasing; at least :data:`LAST` of them.
    :param values: the metric at each step.
    :param at_least: an evaluation whose value is at least this solves the task.
    """
    scores = np.asarray(values, dtype=np.float64)
    if scores.size < LAST or len(steps) != scores.size:
        raise ValueError(f"a run is judged on at least {LAST} evaluations with their steps, got {scores.size}")
    solves = scores >= at_least
    hits = np.flatnonzero(solves)
    first = int(hits[0]) if hits.size else None
    return RunOutcome(
        solved=int(solves[-LAST:].sum()) >= MAJORITY,
        first_solved=None if first is None else int(steps[first]),
        kept=None if first is None else float(solves[first:].mean()),
        auc=float(scores.mean()),
        final=float(scores[-LAST:].mean()),
    )


@dataclass(frozen=True)
class Reliability:
    """How a set of runs (seeds, maps) of one command learned."""

    runs: int
    solved: int  # runs solved at the end
    ever_solved: int  # runs that solved the task at some evaluation
    lost: int  # runs that solved it and are not solved at the end
    kept: float | None  # mean over the ever-solved runs of the share of evaluations kept solved
    median_first_solved: float | None  # median step of the first solving evaluation, over the ever-solved runs
    final_mean: float  # mean over runs of the final score (the metric over the last LAST evaluations)
    final_min: float
    final_max: float


def reliability(outcomes: Sequence[RunOutcome]) -> Reliability:
    """The :class:`Reliability` of the runs whose outcomes are given (at least one)."""
    if not outcomes:
        raise ValueError("no runs to judge")
    ever = [o for o in outcomes if o.first_solved is not None]
    finals = [o.final for o in outcomes]
    return Reliability(
        runs=len(outcomes),
        solved=sum(o.solved for o in outcomes),
        ever_solved=len(ever),
        lost=sum(o.lost for o in outcomes),
        kept=float(np.mean([o.kept for o in ever])) if ever else None,
        median_first_solved=float(np.median([o.first_solved for o in ever])) if ever else None,
        final_mean=float(np.mean(finals)),
        final_min=min(finals),
        final_max=max(finals),
    )


@dataclass(frozen=True)
class Parity:
    """Condition B against condition A over the same tasks (maps) and seeds (:func:`parity`)."""

    auc: Estimate  # P(B > A) on the area under the curve, with its 95% interval
    final: Estimate  # P(B > A) on the final score
    solved_a: int
    solved_b: int
    runs_a: int
    runs_b: int
    fisher_p: float  # Fisher's exact test, two-sided, on the solved counts

    @property
    def alike(self) -> bool:
        """The module's rule: both intervals hold 0.5 and Fisher's p is at least :data:`ALPHA`."""
        return all(e.low <= 0.5 <= e.high for e in (self.auc, self.final)) and self.fisher_p >= ALPHA


def parity(a: Sequence[Sequence[RunOutcome]], b: Sequence[Sequence[RunOutcome]], rng: np.random.Generator) -> Parity:
    """Condition B against condition A; ``a[t]`` and ``b[t]`` are the runs of each on task ``t`` (the same
    number of runs per task within a condition).

    :param a: condition A's outcomes, by task.
    :param b: condition B's outcomes, by task.
    :param rng: the bootstrap's generator.
    """
    if len(a) != len(b) or not a:
        raise ValueError(f"the conditions must have the same tasks, got {len(a)} and {len(b)}")

    def scores(runs: Sequence[Sequence[RunOutcome]], field: str) -> np.ndarray:  # [runs, tasks]
        return np.array([[getattr(o, field) for o in task] for task in runs], dtype=np.float64).T

    solved_a, solved_b = (sum(o.solved for task in runs for o in task) for runs in (a, b))
    runs_a, runs_b = (sum(len(task) for task in runs) for runs in (a, b))
    table = [[solved_a, runs_a - solved_a], [solved_b, runs_b - solved_b]]
    return Parity(
        auc=improvement_probability(scores(b, "auc"), scores(a, "auc"), rng),
        final=improvement_probability(scores(b, "final"), scores(a, "final"), rng),
        solved_a=solved_a,
        solved_b=solved_b,
        runs_a=runs_a,
        runs_b=runs_b,
        fisher_p=float(scipy.stats.fisher_exact(table).pvalue),
    )
