"""The second edition's step budgets per cell, with the first edition's runs as the pilot.

A cell is a condition of an experiment, its runs differing only in map and seed (:data:`CELLS`). The first
edition ran every run for 8,000 steps, so a cell still improving then is reported as not converged within the
pilot, its budget the cap: the pilot says nothing of how long it needs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from dqn_transfer.analysis.budget import (
    PER_STEPS,
    Budget,
    BudgetRule,
    budgets_per_cell,
)
from dqn_transfer.experiments.claims import exchange_condition
from dqn_transfer.experiments.raw_data import DataError, RunData
from dqn_transfer.experiments.scoring import group, learner, learners, mode, team_size


@dataclass(frozen=True)
class CellKind:
    """How an experiment's runs form cells: the table's columns and a run's cell, learner and mode first."""

    columns: tuple[str, ...]
    cell: Callable[[RunData], tuple[Any, ...]]


def _exchange_cell(run: RunData) -> tuple[Any, ...]:
    return learner(run), mode(run), exchange_condition(run)


CELLS = {
    "claim2": CellKind(("learner", "mode", "m"), lambda run: (learner(run), mode(run), team_size(run))),
    "hypothesis": CellKind(("learner", "mode", "exchange"), _exchange_cell),
    "hypothesis_shared": CellKind(("learner", "mode", "exchange"), _exchange_cell),
}


HEADINGS = ("runs", "converged step", "budget", "capped", "slope at budget", "final slope")


@dataclass(frozen=True)
class BudgetRow:
    """One cell: its values of the table's columns, its number of pilot runs and its budget."""

    cell: tuple[Any, ...]
    runs: int
    budget: Budget


@dataclass(frozen=True)
class PilotBudgets:
    """The budget rule on every cell of one experiment's pilot, with the rule's parameters."""

    experiment: str
    columns: tuple[str, ...]
    rows: list[BudgetRow]
    rule: BudgetRule


def pilot_budgets(runs: Sequence[RunData], rule: BudgetRule) -> PilotBudgets:
    """The budget of every cell of a pilot experiment, the primary learner's cells first, then by mode, then
    in the pilot's order.

    :param runs: one experiment's runs (:func:`~dqn_transfer.experiments.raw_data.read_data`), one of
        :data:`CELLS`.
    :param rule: the rule's parameters, its threshold a slope in score per 1,000 steps.
    """
    experiments = sorted({run.experiment for run in runs})
    if not experiments:
        raise DataError("the pilot holds no runs")
    if len(experiments) > 1:
        raise DataError(f"a pilot is one experiment's runs, got those of {', '.join(experiments)}")
    experiment = experiments[0]
    if experiment not in CELLS:
        raise DataError(f"no budget cells for experiment {experiment!r} (defined for {', '.join(CELLS)})")
    kind = CELLS[experiment]
    cells = group(runs, kind.cell)
    rank = {name: index for index, name in enumerate(learners(runs))}
    ordered = sorted(cells, key=lambda cell: (rank[cell[0]], cell[1]))  # stable: then in the pilot's order
    budgets = budgets_per_cell({cell: [run.score_curve() for run in cells[cell]] for cell in ordered}, rule)
    rows = [BudgetRow(cell, len(cells[cell]), budgets[cell]) for cell in ordered]
    return PilotBudgets(experiment, kind.columns, rows, rule)


def _slope(value: float | None) -> str:
    return "beyond the pilot" if value is None else f"{value:+.4f}"


def _converged(budget: Budget) -> str:
    if budget.converged_step is None:
        return f"not converged within the pilot ({budget.pilot_steps:,})"
    return f"{budget.converged_step:,}"


def format_pilot_budgets(result: PilotBudgets) -> str:
    """The budgets in Markdown: the rule, one row per cell, and how many cells converged within the pilot.

    :param result: :func:`pilot_budgets`' result.
    """
    rule = result.rule
    lines = [
        f"{result.experiment}: slope = least-squares slope of a run's last {rule.fraction:.0%} of evaluations "
        f"(at least {rule.min_points}), in score per {PER_STEPS:,} steps, median over the cell's runs; "
        "converged step = the first evaluation step S such that the slope of the runs cut at S, and at every "
        f"later step, is below "
        f"{rule.threshold:g}; budget = min({rule.cap:,}, {rule.safety:g} x converged step, rounded up to a "
        f"multiple of {rule.round_to:,}); final slope: at the pilot's end.",
        "",
        "| " + " | ".join((*result.columns, *HEADINGS)) + " |",
        "|" + "---|" * len(result.columns) + "---:|---:|---:|---|---:|---:|",
    ]
    for row in result.rows:
        b = row.budget
        cells = " | ".join(str(value) for value in row.cell)
        lines.append(
            f"| {cells} | {row.runs} | {_converged(b)} | {b.budget:,}{' (cap)' if b.capped else ''} "
            f"| {'yes' if b.capped else 'no'} | {_slope(b.slope_at_budget)} | {_slope(b.final_slope)} |"
        )
    stuck = [row for row in result.rows if not row.budget.converged]
    lines += ["", f"{len(result.rows) - len(stuck)} of {len(result.rows)} cells converged within the pilot."]
    if stuck:
        lines.append(
            f"{len(stuck)} did not: their median run's slope was still at or above {rule.threshold:g} at the "
            f"pilot's end, so the pilot cannot say how long they need; their budget is the cap, not a measurement."
        )
    return "\n".join(lines)
