"""The fair tuning protocol: one Optuna search per learner x knowledge-exchange method, on tuning maps.

    python -m dqn_transfer.cli.tune --out tuning                        # all ten searches: ~26 min on 2 cores
    python -m dqn_transfer.cli.tune --out /tmp/t --profile quick        # smoke run: 46 s of CPU, NOT evidence
    python -m dqn_transfer.cli.tune --out tuning --only sarsa_best double_dqn_best
    python -m dqn_transfer.cli.tune --out tuning --report-only          # tuned.yaml, table, figure from tuning.jsonl
    python -m dqn_transfer.cli.tune --out tuning --apply                # tuned.yaml into conf/tuned/ (the methods')

Each search is ``python -m dqn_transfer.cli.train -m experiment=tune/<learner>_<method>`` into
``OUT/runs/<learner>_<method>/`` (its log in ``OUT/logs/``); ``--parallel`` searches run at once, each
one's trials one after another. Its trials go into ``OUT/tuning.jsonl`` (one JSON line each), and from
that file alone come ``OUT/tuned.yaml`` (each search's best values), ``OUT/tuning.md`` (the table) and
``OUT/tuning_sensitivity.png`` (the dose-response figure). A search finished before with the same
settings is reused; a directory holding another one's runs is an error, never overwritten.
"""

from __future__ import annotations

import sys
from pathlib import Path

from dqn_transfer.analysis.tuning import TuningError
from dqn_transfer.cli.console import docstring_parser, exit_with
from dqn_transfer.experiments.sweeps import ReproduceError
from dqn_transfer.experiments.tuning import PROFILES, SEARCHES, TRIALS_FILE, analyse, apply_tuned, search_named, tune


def main(argv: list[str] | None = None) -> int:
    """Run the searches and analyse them; exit 1 with one ``error:`` message on a failure or bad trials."""
    parser = docstring_parser(__doc__)
    parser.add_argument("--out", type=Path, required=True, help="output directory (runs/, logs/, tuning.jsonl, ...)")
    parser.add_argument("--profile", choices=sorted(PROFILES), default="full")
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="SEARCH",
        default=[s.name for s in SEARCHES],
        help=f"searches to run (default: all of {' '.join(s.name for s in SEARCHES)})",
    )
    parser.add_argument("--parallel", type=int, default=2, help="searches at once (default 2, one per core)")
    parser.add_argument("--report-only", action="store_true", help=f"no training: analyse OUT/{TRIALS_FILE} as it is")
    parser.add_argument(
        "--apply",
        action="store_true",
        help="no training: write OUT/tuned.yaml's values into conf/tuned/, which the methods compose",
    )
    args = parser.parse_args(argv)
    if args.parallel < 1:
        parser.error(f"--parallel must be >= 1, got {args.parallel}")
    try:
        searches = [search_named(name) for name in dict.fromkeys(args.only)]
        if args.apply:
            written = apply_tuned(args.out)
        elif args.report_only:
            written = analyse(args.out)
        else:
            written = tune(searches, args.profile, args.out, args.parallel)
    except (TuningError, ReproduceError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    exit_with(main)
