"""Plot the evaluation curves of run directories: a person would rather look than read.

    python -m dqn_transfer.cli.plot RUN_DIR [RUN_DIR ...] --out fig.png [--metric team_return]

A RUN_DIR is a Hydra run directory (it holds ``metrics.jsonl``) or any directory above some, e.g. a
multirun sweep directory: every run below it is used. Runs are grouped by what differs between their
configs (``.hydra/config.yaml``), ignoring the seed: each group is drawn as its mean over seeds with a
95% percentile-bootstrap band and each run as a thin line (one line when the group has one run);
``--total-steps`` starts each run at the steps spent before it (a pretrained source, a curriculum's
stages). Runs without a readable config
get one line each. A directory that is not a usable run (no ``metrics.jsonl``, no evaluations yet: a
refused run's stub) is skipped with a ``skipped DIR: REASON`` line on stderr; only when none is left
is it an error. The reproduction report draws its figures with the same helpers.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dqn_transfer.analysis.plots import group_runs, plot_groups
from dqn_transfer.analysis.runs import find_run_dirs
from dqn_transfer.cli.study_console import reading_runs


def main(argv: list[str] | None = None) -> int:
    """Write the figure and say what it shows; exit 1 with one ``error:`` line on bad input."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories (or directories above them)")
    parser.add_argument("--out", required=True, type=Path, help="output image, e.g. fig.png")
    parser.add_argument(
        "--metric",
        default="team_return",
        help="metrics.jsonl key: team_return (default), success_rate, trap_rate, episode_length",
    )
    parser.add_argument("--title", default=None)
    parser.add_argument(
        "--total-steps",
        action="store_true",
        help="start each run's curve at the steps spent before it (its source's pretraining, "
        "a curriculum's stages): conditions compare at equal total budgets",
    )
    args = parser.parse_args(argv)
    return reading_runs(lambda: _plot(args))


def _plot(args: argparse.Namespace) -> int:
    run_dirs = find_run_dirs(args.runs)
    groups = group_runs(run_dirs)
    path = plot_groups(groups, args.metric, args.out, args.title, total_steps=args.total_steps)
    sizes = ", ".join(f"{label} ({len(d)})" for label, d in groups.items())
    print(f"wrote {path}: {len(run_dirs)} runs in {len(groups)} group(s): {sizes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
