"""The study's report again from its data, for either edition; and the first edition's runs.

    python scripts/reproduce.py --profile quick --out /tmp/study      # smoke run: minutes, NOT evidence
    python scripts/reproduce.py --profile full --out results/v1       # the evidence: 9 min on 2 cores
    dqn-transfer-report results/v1 --out /tmp/report                  # the report again from its data/,
                                                                      # no training, under a minute
    dqn-transfer-report results                                       # the second edition's, in place
    python scripts/reproduce.py --out results/v1 --report-only          # re-export OUT/runs/ and report
    python scripts/reproduce.py --profile full --out results/v1 --launcher submitit_slurm \\
        --extra hydra.launcher.partition=PART --extra hydra.launcher.timeout_min=60

(``dqn-transfer-report`` and ``python -m dqn_transfer.cli.report`` are the same program.) A results directory
holding ``budgets.md`` is the second edition's (``results/``, rules in ``results/VERDICT_RULES.md``; its runs:
``python -m dqn_transfer.cli.second_edition``), any other the first edition's. The first edition: each
experiment is one Hydra multirun of ``python -m dqn_transfer.cli.train -m experiment=<name>``
(``conf/experiment/``) into ``OUT/runs/<name>/``; ``--launcher joblib`` (the default, from the
``sweep`` extra) runs ``--n-jobs`` jobs at a time. The runs' evaluations are then exported to
``OUT/data/<name>.jsonl`` (one JSON line per run, with its config) and the report is computed from
those files alone, by the rules of ``results/v1/VERDICT_RULES.md``:

- hypothesis, hypothesis_shared: a group that exchanges knowledge learns better than the same group without;
- claim1: with one treasure, cooperation gives no advantage over competition;
- claim2: as the team grows, deliberative > cooperative > competitive;
- transfer: starting from a trained agent speeds up learning (with exploration-matched baselines and
  the source's cost).

A sweep directory already complete for the same settings is reused; one holding other or unfinished
runs is an error, never overwritten.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dqn_transfer.analysis.runs import skipped_runs_on_stderr
from dqn_transfer.cli.console import run_study_command
from dqn_transfer.experiments.raw_data import DATA_DIR
from dqn_transfer.experiments.report import export_data, write_report
from dqn_transfer.experiments.second_edition import BUDGETS_TABLE
from dqn_transfer.experiments.second_edition_report import write_report as second_edition_report
from dqn_transfer.experiments.sweeps import (
    EXPERIMENTS,
    PROFILES,
    ReproduceError,
    choose_launcher,
    chosen_experiments,
    run_experiment,
)


def main(argv: list[str] | None = None) -> int:
    """Run the sweeps and write the report; exit 1 with one ``error:`` message on a failure."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 1)[1],
    )
    parser.add_argument(
        "results",
        nargs="?",
        type=Path,
        help="a results directory holding data/: only write its report (into --out, default itself)",
    )
    parser.add_argument("--profile", choices=sorted(PROFILES), default="quick")
    parser.add_argument("--out", type=Path, help="output directory (runs/, data/, figures, REPORT.md)")
    parser.add_argument(
        "--only",
        default=",".join(EXPERIMENTS),
        help=f"comma-separated subset of {','.join(EXPERIMENTS)} (default: all)",
    )
    parser.add_argument(
        "--launcher",
        default=None,
        help="Hydra launcher: joblib (default; the sweep extra, else basic), basic (one job at "
        "a time), submitit_slurm (the slurm extra), ...",
    )
    parser.add_argument("--n-jobs", type=int, default=2, help="parallel jobs with --launcher joblib (default 2)")
    parser.add_argument(
        "--extra",
        action="append",
        default=[],
        metavar="OVERRIDE",
        help="extra Hydra override for every sweep, e.g. hydra.launcher.partition=PART (repeatable)",
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="run nothing: export the runs already in OUT/runs/ and write the report",
    )
    args = parser.parse_args(argv)
    if args.results is None and args.out is None:
        parser.error("give a results directory to report on, or --out to run the study into")
    return run_study_command(lambda: _report(args))


def _report(args: argparse.Namespace) -> Path:
    """The report of ``args.results`` (either edition), or the first edition's runs into ``args.out`` and
    their report; prints the report's verdict lines."""
    if args.results is not None:
        results = args.results.expanduser()
        if not (results / DATA_DIR).is_dir():
            raise ReproduceError(f"{args.results} has no {DATA_DIR}/ directory of run data")
        out = (args.out or args.results).expanduser()
        if (results / BUDGETS_TABLE).is_file():
            report = second_edition_report(results, out)
        else:
            report = write_report(results / DATA_DIR, out)
    else:
        only = chosen_experiments(args.only, EXPERIMENTS, args.n_jobs)
        launcher = None if args.report_only else choose_launcher(args.launcher)  # refused before anything runs
        out = args.out.expanduser().resolve()
        out.mkdir(parents=True, exist_ok=True)
        if launcher is not None:  # None with --report-only
            print(f"profile {args.profile}: {PROFILES[args.profile].description}", flush=True)
            for name in only:
                run_experiment(name, args.profile, out, launcher, args.n_jobs, args.extra)
        with skipped_runs_on_stderr():
            data = export_data(out)
        report = write_report(data, out)
    for line in report.read_text().splitlines():
        if line.startswith("| ") and "**" in line:
            print("  " + line)
    return report


if __name__ == "__main__":
    sys.exit(main())
