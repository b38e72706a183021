"""Export runs for the field's tools.

    dqn-transfer-export marl-eval RUN_DIR... --out results.json
    dqn-transfer-export marl-eval --data results/v1/data/*.jsonl --out study.json

writes marl-eval's JSON (environment -> task -> algorithm -> seed_N -> step_k; docs/integrations.md). A
directory that is not a usable run is skipped with a ``skipped DIR: REASON`` line; what marl-eval's
processing would not accept (tasks without the same algorithms, seeds or evaluations) is a ``warning:``
line. Bad input (no runs, an unreadable file, an existing --out) is one ``error:`` line, exit 1, and
nothing written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dqn_transfer.analysis.marl_eval import ENVIRONMENT, layout_problems
from dqn_transfer.analysis.runs import EvaluationError, skipped_runs_on_stderr
from dqn_transfer.cli.console import exit_with
from dqn_transfer.experiments.export import data_tree, run_dirs_tree
from dqn_transfer.experiments.raw_data import DataError
from dqn_transfer.experiments.scoring import FINAL_TAIL


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="dqn-transfer-export", description=__doc__.split("\n\n")[0])
    formats = top.add_subparsers(dest="format", required=True, metavar="FORMAT")
    marl = formats.add_parser("marl-eval", help="marl-eval's JSON (InstaDeep's id-marl-eval)")
    marl.add_argument("runs", nargs="*", metavar="RUN_DIR", help="run directories (a sweep stands for its runs)")
    marl.add_argument(
        "--data", nargs="+", default=[], metavar="FILE", help="the study's raw data (results/v1/data/*.jsonl)"
    )
    marl.add_argument("--out", required=True, type=Path, help="the JSON file to write (must not exist)")
    marl.add_argument(
        "--environment", default=ENVIRONMENT, help=f"the run directories' environment name (default: {ENVIRONMENT})"
    )
    marl.add_argument(
        "--final-tail",
        type=float,
        default=FINAL_TAIL,
        help=f"absolute_metrics: the mean of this fraction of the last evaluations (default: {FINAL_TAIL})",
    )
    return top


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        if args.out.exists():
            raise EvaluationError(f"{args.out} exists: give a new --out")
        if not args.runs and not args.data:
            raise EvaluationError("no run directory and no --data file given")
        if not 0.0 < args.final_tail <= 1.0:
            raise EvaluationError(f"--final-tail is a fraction in (0, 1], got {args.final_tail}")
        tree = {}
        with skipped_runs_on_stderr():
            if args.runs:
                tree.update(run_dirs_tree(args.runs, args.environment, args.final_tail))
            data = data_tree([Path(p) for p in args.data], args.final_tail)
        if set(tree) & set(data):
            raise EvaluationError(f"environment {sorted(set(tree) & set(data))[0]!r} both in the runs and in --data")
        tree.update(data)
        text = json.dumps(tree, indent=1) + "\n"
        with args.out.open("x") as stream:
            stream.write(text)
    except (EvaluationError, DataError, ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    for problem in layout_problems(tree):
        print(f"warning: {problem} (marl-eval's processing needs them equal)", file=sys.stderr)
    runs = sum(len(seeds) for tasks in tree.values() for algos in tasks.values() for seeds in algos.values())
    print(f"wrote {args.out}: {runs} runs in {len(tree)} environment(s)")
    return 0


def run() -> None:
    exit_with(main)


if __name__ == "__main__":
    run()
