"""The study's second edition after tuning (results/VERDICT_RULES.md): the budget pilots, the full runs, the report.

    python -m dqn_transfer.cli.tune --out results/tuning --profile full           # stage 2: tuning
    python -m dqn_transfer.cli.second_edition pilot --out results                 # stage 3: pilots, budgets
    python -m dqn_transfer.cli.second_edition full --out results                  # stage 4: the evidence, report
    dqn-transfer-report results                                                   # stage 5: REPORT.md again
    python -m dqn_transfer.cli.second_edition pilot --out /tmp/s --profile quick  # smoke run: NOT evidence

``pilot`` runs every experiment (``experiment=v2/<name>``) on the pilot maps (map seeds 2000..) for the
budget rule's cap, keeps the raw data in ``OUT/pilot/data/``, and writes each comparison group's budget to
``OUT/budgets.json`` and ``OUT/budgets.md`` (``--report-only``: from the pilot's data, nothing run).
``full`` runs each comparison group as one Hydra multirun at its budget from ``OUT/budgets.json`` (or
``--budgets FILE``), writes ``OUT/data/<name>.jsonl``, then the report. ``report`` writes ``OUT/REPORT.md``
and its figures from ``OUT/data/``, ``OUT/budgets.md`` and ``OUT/tuning/`` alone (seconds; nothing is run).
A sweep directory already complete for the same settings is reused; one holding other or unfinished runs
is an error, never overwritten.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from dqn_transfer.analysis.runs import skipped_runs_on_stderr
from dqn_transfer.cli.console import add_launcher_options, docstring_parser, exit_with, run_study_command
from dqn_transfer.experiments.raw_data import DATA_DIR
from dqn_transfer.experiments.second_edition import (
    BUDGETS_FILE,
    BUDGETS_TABLE,
    EXPERIMENTS,
    PILOT_DIR,
    PROFILES,
    pilot_budgets,
    run_full,
    run_pilots,
    write_budgets,
)
from dqn_transfer.experiments.second_edition_report import write_report
from dqn_transfer.experiments.sweeps import ReproduceError, choose_launcher, chosen_experiments


def _parser() -> argparse.ArgumentParser:
    parser = docstring_parser(__doc__, prog="python -m dqn_transfer.cli.second_edition")
    parser.add_argument("stage", choices=["pilot", "full", "report"])
    parser.add_argument("--out", type=Path, required=True, help="the study's directory (results/ for the evidence)")
    parser.add_argument("--profile", choices=sorted(PROFILES), default="full")
    parser.add_argument("--only", default=",".join(EXPERIMENTS), help=f"a subset of {','.join(EXPERIMENTS)}")
    add_launcher_options(parser)
    parser.add_argument("--budgets", type=Path, help=f"full: the budgets file (default OUT/{BUDGETS_FILE})")
    parser.add_argument("--report-only", action="store_true", help="pilot: budgets from OUT/pilot/data/, run nothing")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one stage; exit 1 with one ``error:`` line on a failure."""
    args = _parser().parse_args(argv)
    return run_study_command(lambda: _run_stage(args))


def _run_stage(args: argparse.Namespace) -> Path:
    """The stage ``args.stage``; returns the file it wrote last (``budgets.json`` or ``REPORT.md``)."""
    names = chosen_experiments(args.only, EXPERIMENTS, args.n_jobs)
    out = args.out.expanduser().resolve()
    launcher = None if args.report_only or args.stage == "report" else choose_launcher(args.launcher)
    print(f"profile {args.profile}: {PROFILES[args.profile].description}", flush=True)
    if args.stage == "pilot":
        data = out / PILOT_DIR / DATA_DIR
        if launcher is not None:
            with skipped_runs_on_stderr():
                data = run_pilots(names, args.profile, out, launcher, args.n_jobs)
        profile = PROFILES[args.profile]
        piloted = [name for name in EXPERIMENTS if (data / f"{name}.jsonl").is_file()]  # --only X keeps the rest
        write_budgets(out, pilot_budgets(data, piloted, profile), profile.rule)
        print((out / BUDGETS_TABLE).read_text())
        return out / BUDGETS_FILE
    if args.stage == "full":
        if launcher is None:
            raise ReproduceError("--report-only applies to the pilot stage")
        with skipped_runs_on_stderr():
            run_full(names, args.profile, out, args.budgets or out / BUDGETS_FILE, launcher, args.n_jobs)
    return write_report(out)


if __name__ == "__main__":
    exit_with(main)
