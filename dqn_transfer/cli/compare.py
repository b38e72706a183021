"""Transfer metrics (Taylor & Stone 2009) of transfer runs against baseline runs, with bootstrap 95% CIs over seeds.

    python -m dqn_transfer.cli.compare --transfer outputs/tr/* --baseline outputs/base/* [--threshold X]

(the shell expands the globs; a sweep directory stands for every run below it). Prints a Markdown
table; see :func:`dqn_transfer.analysis.compare.compare_runs` for what each row means. A directory that
is not a usable run is skipped with a ``skipped DIR: REASON`` line on stderr.
"""

from __future__ import annotations

import argparse
import sys

from dqn_transfer.analysis.compare import compare_runs, format_table
from dqn_transfer.cli.study_console import reading_runs


def main(argv: list[str] | None = None) -> int:
    """Print the transfer-vs-baseline Markdown table; exit 1 with one ``error:`` line on bad input."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--transfer", nargs="+", required=True, metavar="DIR", help="transfer run dirs")
    parser.add_argument("--baseline", nargs="+", required=True, metavar="DIR", help="baseline run dirs")
    parser.add_argument("--metric", default="team_return", help="metrics.jsonl key (default: team_return)")
    parser.add_argument(
        "--transfer-offset",
        type=int,
        default=0,
        metavar="STEPS",
        help="env steps the transfer runs spent before their step 0 (pretraining, a curriculum's "
        "earlier stages): their curves are shifted by it, to compare at equal total steps",
    )
    parser.add_argument("--threshold", type=float, default=None, help="value for time_to_threshold")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap RNG seed")
    args = parser.parse_args(argv)
    return reading_runs(lambda: _print_table(args))


def _print_table(args: argparse.Namespace) -> int:
    results = compare_runs(args.transfer, args.baseline, args.metric, args.threshold, args.seed, args.transfer_offset)
    print(format_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
