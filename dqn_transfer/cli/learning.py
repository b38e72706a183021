"""How reliably the README's commands learn over seeds, and whether the two DQN engines learn alike.

    python -m dqn_transfer.cli.learning run --out results/learning                 # every sweep, then the tables
    python -m dqn_transfer.cli.learning run --out results/learning --only parity   # one sweep
    python -m dqn_transfer.cli.learning table --out results/learning               # the tables from OUT/data/

``run`` runs each sweep (:mod:`dqn_transfer.experiments.learning`: each README command with 10 seeds, and the
engines' parity, 10 seeds on 3 maps each) as a Hydra multirun into ``OUT/runs/<name>/``, keeps its runs'
evaluations in ``OUT/data/<name>.jsonl`` and writes ``OUT/TABLES.md``; ``table`` writes ``OUT/TABLES.md``
from ``OUT/data/`` alone (docs/learning.md holds it). A finished sweep is reused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from dqn_transfer.analysis.runs import skipped_runs_on_stderr
from dqn_transfer.cli.console import docstring_parser, exit_with
from dqn_transfer.cli.study_console import add_launcher_options, run_study_command
from dqn_transfer.experiments.learning import NAMES, TABLES_FILE, run, tables
from dqn_transfer.experiments.raw_data import DATA_DIR
from dqn_transfer.experiments.sweeps import choose_launcher, chosen_experiments
from dqn_transfer.storage.checkpoint import atomic_write


def _parser() -> argparse.ArgumentParser:
    parser = docstring_parser(__doc__, prog="python -m dqn_transfer.cli.learning")
    parser.add_argument("stage", choices=["run", "table"])
    parser.add_argument("--out", type=Path, required=True, help="the sweeps' directory (results/learning)")
    parser.add_argument("--only", default=",".join(NAMES), help=f"run: a subset of {','.join(NAMES)}")
    add_launcher_options(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the stage; exit 1 with one ``error:`` line on a failure."""
    args = _parser().parse_args(argv)
    return run_study_command(lambda: _run_stage(args))


def _run_stage(args: argparse.Namespace) -> Path:
    names = chosen_experiments(args.only, NAMES, args.n_jobs)
    out = args.out.expanduser().resolve()
    if args.stage == "run":
        launcher = choose_launcher(args.launcher)
        with skipped_runs_on_stderr():
            run(names, out, launcher, args.n_jobs)
    text = tables(out / DATA_DIR)
    print(text)
    path = out / TABLES_FILE
    atomic_write(path, text.encode())
    return path


if __name__ == "__main__":
    exit_with(main)
