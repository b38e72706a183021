"""The second edition's power analysis, with the first edition's runs as the pilot.

    python -m dqn_transfer.cli.power --pilot results/v1/data/hypothesis.jsonl [--metric final_score|score]

Prints a Markdown table (:func:`dqn_transfer.experiments.power.format_power_rows`): for each primary
comparison, the pilot's paired difference with maps resampled, its map-level and run-level standard
deviations, and the maps needed for 80% power.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from dqn_transfer.cli.console import error_line, exit_with
from dqn_transfer.experiments.power import METRICS, format_power_rows, power_rows
from dqn_transfer.experiments.raw_data import DataError, read_data


def main(argv: list[str] | None = None) -> int:
    """Print the power table; exit 2 with one ``error:`` line on a pilot that cannot be read or used."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--pilot", required=True, type=Path, metavar="JSONL", help="raw data of the hypothesis experiment"
    )
    parser.add_argument(
        "--metric", choices=sorted(METRICS), default="final_score", help="the run value compared (default: final_score)"
    )
    parser.add_argument("--seed", type=int, default=0, help="bootstrap and simulation RNG seed")
    args = parser.parse_args(argv)

    def table() -> int:
        rows = power_rows(read_data(args.pilot), METRICS[args.metric], np.random.default_rng(args.seed))
        print(format_power_rows(rows, args.metric))
        return 0

    return error_line(table, (DataError, ValueError), 2)  # ValueError: too few maps or runs to analyse


if __name__ == "__main__":
    exit_with(main)
