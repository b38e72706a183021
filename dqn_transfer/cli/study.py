"""The study, any edition (``conf/edition/<name>.yaml``): one stage of tuning, pilots and budgets, runs, report.

    python -m dqn_transfer.cli.study tune  --edition v2 --out results/v2   # stage 2: tuning (~26 min on 2 cores)
    python -m dqn_transfer.cli.study pilot --edition v2 --out results/v2   # stage 3: pilots, budgets (~30 min)
    python -m dqn_transfer.cli.study full  --edition v2 --out results/v2   # stage 4: the runs, REPORT.md (2 h 04 min)
    python -m dqn_transfer.cli.study full  --edition v1 --out results/v1   # the first edition: runs, REPORT.md (9 min)
    dqn-transfer-report results/v2                                         # REPORT.md again, from the data
    python -m dqn_transfer.cli.study pilot --edition v2 --out /tmp/s --profile quick   # smoke run: NOT evidence

An edition runs the stages its file lists. ``tune`` runs the tuning's searches (``--only`` a subset, ``--n-jobs``
at once) into ``OUT/tuning/``: its trials, ``tuned.yaml``, table and figure (``--report-only``: from its
trials, nothing run; ``--apply``: ``tuned.yaml`` into ``conf/tuned/``, which the methods compose). ``pilot`` runs
every experiment on the pilot maps, keeps the raw data in ``OUT/pilot/data/``, and writes each comparison
group's budget to ``OUT/budgets.json`` and ``OUT/budgets.md`` (``--report-only``: from the pilot's data).
``full`` runs each experiment (with budgets: each comparison group at its budget from ``OUT/budgets.json`` or
``--budgets FILE``), writes ``OUT/data/<name>.jsonl`` and the manifest, then the report (``--report-only``:
exports what ``OUT/runs/`` holds, runs nothing). ``report`` writes ``OUT/REPORT.md`` and its figures from
``OUT``'s data alone. A sweep directory already complete for the same settings is reused; one holding other
or unfinished runs is an error, never overwritten.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from dqn_transfer.analysis.runs import skipped_runs_on_stderr
from dqn_transfer.cli.console import docstring_parser, exit_with
from dqn_transfer.cli.study_console import add_launcher_options, print_verdicts, run_study_command
from dqn_transfer.experiments import tuning
from dqn_transfer.experiments.cell_runs import write_maps
from dqn_transfer.experiments.edition import (
    BUDGETS_FILE,
    BUDGETS_TABLE,
    MAPS_FILE,
    MAPS_TABLE,
    PILOT_DIR,
    STAGES,
    TUNING_DIR,
    Edition,
    load_edition,
)
from dqn_transfer.experiments.pipeline import (
    pilot_budgets,
    pilot_maps,
    pilot_rule,
    record_stage,
    run_full,
    run_pilots,
    write_budgets,
    write_report,
)
from dqn_transfer.experiments.raw_data import DATA_DIR
from dqn_transfer.experiments.sweeps import ReproduceError, choose_launcher, chosen_experiments


def _parser() -> argparse.ArgumentParser:
    parser = docstring_parser(__doc__, prog="python -m dqn_transfer.cli.study")
    parser.add_argument("stage", choices=STAGES)
    parser.add_argument("--edition", required=True, help="conf/edition/<EDITION>.yaml, e.g. v1 or v2")
    parser.add_argument("--out", type=Path, required=True, help="the edition's directory (results/vN for evidence)")
    parser.add_argument("--profile", choices=["full", "quick"], default="full", help="full: the evidence (default)")
    parser.add_argument("--only", help="a comma-separated subset of the edition's experiments (tune: searches)")
    add_launcher_options(parser)
    parser.add_argument(
        "--extra",
        action="append",
        default=[],
        metavar="OVERRIDE",
        help="an extra Hydra override for every sweep, e.g. hydra.launcher.partition=PART (repeatable)",
    )
    parser.add_argument("--budgets", type=Path, help=f"full: the budgets file (default OUT/{BUDGETS_FILE})")
    parser.add_argument("--report-only", action="store_true", help="tune, pilot, full: analyse what OUT holds")
    parser.add_argument("--apply", action="store_true", help=f"tune: OUT/{TUNING_DIR}/tuned.yaml into conf/tuned/")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one stage; exit 1 with one ``error:`` line on a failure."""
    args = _parser().parse_args(argv)
    return run_study_command(lambda: _run_stage(args))


def _run_stage(args: argparse.Namespace) -> Path:
    """The stage ``args.stage`` of ``args.edition``; returns the file it wrote last. A stage that runs anything
    adds its wall time to ``OUT/stages.json``, interrupted or not."""
    edition = load_edition(args.edition)
    edition.check_stage(args.stage)
    out = args.out.expanduser().resolve()
    runs = not (args.report_only or args.apply or args.stage == "report")
    start = time.perf_counter()
    try:
        return _tune(args, edition, out / TUNING_DIR) if args.stage == "tune" else _runs_stage(args, edition, out)
    finally:
        if runs and (out / TUNING_DIR if args.stage == "tune" else out).is_dir():
            record_stage(out, args.stage, time.perf_counter() - start)


def _runs_stage(args: argparse.Namespace, edition: Edition, out: Path) -> Path:
    """The pilot, full or report stage."""
    names = chosen_experiments(args.only or ",".join(edition.experiments), edition.experiments, args.n_jobs)
    profile = edition.profile(args.profile)
    launcher = None if args.report_only or args.stage == "report" else choose_launcher(args.launcher)
    print(f"edition {edition.name}, profile {args.profile}: {profile.description}", flush=True)
    if args.stage == "pilot" and edition.cells:
        names = [name for name in names if any(cell.experiment == name for cell in edition.cells)]
        if launcher is not None:
            with skipped_runs_on_stderr():
                run_pilots(edition, names, args.profile, out, launcher, args.n_jobs, args.extra)
        write_maps(out, pilot_maps(edition, out, names, profile))
        print((out / MAPS_TABLE).read_text())
        return out / MAPS_FILE
    if args.stage == "pilot":
        data = out / PILOT_DIR / DATA_DIR
        if launcher is not None:
            with skipped_runs_on_stderr():
                data = run_pilots(edition, names, args.profile, out, launcher, args.n_jobs, args.extra)
        piloted = [name for name in edition.experiments if (data / f"{name}.jsonl").is_file()]  # --only keeps the rest
        write_budgets(out, pilot_budgets(edition, data, piloted, profile), pilot_rule(edition, profile))
        print((out / BUDGETS_TABLE).read_text())
        return out / BUDGETS_FILE
    if args.stage == "full":
        with skipped_runs_on_stderr():
            run_full(edition, names, args.profile, out, launcher, args.n_jobs, args.budgets, args.extra)
    report = write_report(edition, out)
    print_verdicts(report)
    return report


def _tune(args: argparse.Namespace, edition: Edition, out: Path) -> Path:
    """The tuning stage into ``out``: each tuning cell's searches (``--only``: those named), or
    (``--report-only``) their analysis, or (``--apply``) the tuned values into ``conf/tuned/``; prints every
    file written, returns ``out``."""
    if args.n_jobs < 1:
        raise ReproduceError(f"--n-jobs must be >= 1, got {args.n_jobs}")
    only = [name.strip() for name in (args.only or "").split(",") if name.strip()]
    known = [name for cell in edition.tuning for name in cell.searches]
    unknown = [name for name in only if name not in known]
    if unknown:
        raise ReproduceError(f"unknown search {unknown[0]!r} (choose from {', '.join(dict.fromkeys(known))})")
    if args.apply and any(cell.name for cell in edition.tuning):
        raise ReproduceError(f"edition {edition.name} runs with its tuned values from OUT: --apply has nothing to do")
    written: list[Path] = []
    cells = []  # (searches, overrides, directory) of each cell to tune: all in one pool
    for cell in edition.tuning:
        cell_dir = out / cell.name
        if args.apply:
            written += tuning.apply_tuned(cell_dir)
        elif args.report_only:
            written += tuning.analyse(cell_dir)
        elif searches := [tuning.search_named(name) for name in cell.searches if not only or name in only]:
            cells.append((searches, (*cell.overrides, *tuning.PROFILES[args.profile]), cell_dir))
    if cells:
        written += tuning.tune(cells, args.n_jobs, edition.trials_per_dimension)
    for path in written:
        print(path)
    return out


if __name__ == "__main__":
    exit_with(main)
