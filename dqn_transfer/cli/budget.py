"""The second edition's step budgets per cell, with the first edition's runs as the pilot.

    python -m dqn_transfer.cli.budget --pilot results/v1/data/claim2.jsonl --threshold 0.01 \\
        [--safety 1.5] [--cap 32000] [--round-to 1000] [--fraction 0.2]

Prints a Markdown table (:func:`dqn_transfer.experiments.budgets.format_pilot_budgets`): for each cell of the
pilot (learner x mode x team size for ``claim2``, learner x mode x exchange for ``hypothesis``), the step by
which its median run stopped improving, the budget the rule gives, whether the cap set it, and the median
plateau slope at the budget and at the pilot's end. A cell not converged within the pilot says so.
"""

from __future__ import annotations

from pathlib import Path

from dqn_transfer.analysis.budget import CAP, FRACTION, ROUND_TO, SAFETY, BudgetRule
from dqn_transfer.cli.console import OneLineErrors, error_line, exit_with
from dqn_transfer.experiments.budgets import format_pilot_budgets, pilot_budgets
from dqn_transfer.experiments.raw_data import DataError, read_data


def main(argv: list[str] | None = None) -> int:
    """Print the budget table; exit 2 with one ``error:`` line on a pilot that cannot be read or used, or a
    bad parameter of the rule."""
    parser = OneLineErrors(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--pilot", required=True, type=Path, metavar="JSONL", help="raw data of one experiment (results/v1/data/)"
    )
    parser.add_argument(
        "--threshold", required=True, type=float, help="converged below this slope, in score per 1,000 steps"
    )
    parser.add_argument("--safety", type=float, default=SAFETY, help=f"budget / converged step (default {SAFETY})")
    parser.add_argument("--cap", type=int, default=CAP, help=f"the largest budget, in steps (default {CAP})")
    parser.add_argument(
        "--round-to", type=int, default=ROUND_TO, help=f"budgets are multiples of this (default {ROUND_TO})"
    )
    parser.add_argument(
        "--fraction", type=float, default=FRACTION, help=f"the tail of a curve fitted (default {FRACTION})"
    )
    args = parser.parse_args(argv)

    def table() -> int:
        rule = BudgetRule(args.threshold, args.safety, args.cap, args.round_to, args.fraction)
        print(format_pilot_budgets(pilot_budgets(read_data(args.pilot), rule)))
        return 0

    return error_line(table, (DataError, ValueError), 2)  # ValueError: a bad parameter, or too few evaluations


if __name__ == "__main__":
    exit_with(main)
