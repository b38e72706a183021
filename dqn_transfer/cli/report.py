"""The study's report again from a results directory's data, for any edition; no training.

    dqn-transfer-report results/v2                     # the second edition's REPORT.md and figures, in place
    dqn-transfer-report results/v1 --out /tmp/report   # the first edition's, elsewhere (the same bytes)
    dqn-transfer-report results/v3 --repeat /tmp/again --out results   # with a repeat's stage times beside

(``dqn-transfer-report`` and ``python -m dqn_transfer.cli.report`` are the same program.) The directory's
``data/manifest.json`` names its edition (``conf/edition/<name>.yaml``), whose analysis writes the report from
``data/`` and what the edition's stages wrote beside it (``budgets.md``, ``tuning/``) alone. The runs are
``python -m dqn_transfer.cli.study``'s. ``--repeat DIR``: ``DIR`` holds every stage run again from scratch
(``study tune``, ``pilot``, ``full`` with ``--out DIR``); its stage times, code, dates and machine and its run
records' digest are kept in the directory's ``repeat.json``, and the third edition's report states them beside
its own stage times, with whether the repeat's run records are its own byte for byte.
"""

from __future__ import annotations

from pathlib import Path

from dqn_transfer.cli.console import docstring_parser, exit_with
from dqn_transfer.cli.study_console import print_verdicts, run_study_command
from dqn_transfer.experiments.edition import edition_of
from dqn_transfer.experiments.pipeline import record_repeat, write_report
from dqn_transfer.experiments.raw_data import DATA_DIR
from dqn_transfer.experiments.sweeps import ReproduceError


def main(argv: list[str] | None = None) -> int:
    """Write the report; exit 1 with one ``error:`` line on a directory that cannot be reported on."""
    parser = docstring_parser(__doc__)
    parser.add_argument("results", type=Path, help="a results directory holding data/")
    parser.add_argument("--out", type=Path, help="where REPORT.md and its figures go (default: the directory)")
    parser.add_argument("--edition", help="the edition, if data/manifest.json does not name one")
    parser.add_argument("--repeat", type=Path, help="a directory every stage ran into again: record its times first")
    args = parser.parse_args(argv)
    return run_study_command(lambda: _report(args.results.expanduser(), args.out, args.edition, args.repeat))


def _report(results: Path, out: Path | None, edition: str | None, repeat: Path | None = None) -> Path:
    if not (results / DATA_DIR).is_dir():
        raise ReproduceError(f"{results} has no {DATA_DIR}/ directory of run data")
    if repeat is not None:
        print(f"wrote {record_repeat(results, repeat.expanduser())}")
    report = write_report(edition_of(results, edition), results, None if out is None else out.expanduser())
    print_verdicts(report)
    return report


if __name__ == "__main__":
    exit_with(main)
