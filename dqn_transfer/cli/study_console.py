"""How the study's commands read runs and end (what they wrote, or one ``error:`` line), and their
launcher options."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

from dqn_transfer.analysis.runs import EvaluationError, skipped_runs_on_stderr
from dqn_transfer.analysis.tuning import TuningError
from dqn_transfer.cli.console import error_line
from dqn_transfer.experiments.raw_data import DataError
from dqn_transfer.experiments.sweeps import ReproduceError


def reading_runs(body: Callable[[], int]) -> int:
    """:func:`error_line` for the commands that read run directories: each one skipped is a line on stderr
    (:func:`~dqn_transfer.analysis.runs.skipped_runs_on_stderr`), one that cannot be read ends in exit code 1.

    :param body: the command's work, returning its exit code
    """
    with skipped_runs_on_stderr():
        return error_line(body, (EvaluationError, ValueError, OSError), 1)


def add_launcher_options(parser: argparse.ArgumentParser) -> None:
    """``--launcher`` and ``--n-jobs``: how a study command runs its Hydra sweeps
    (:func:`~dqn_transfer.experiments.sweeps.choose_launcher`).

    :param parser: the command's parser
    """
    parser.add_argument("--launcher", default=None, help="Hydra launcher: joblib (default), basic, submitit_slurm")
    parser.add_argument("--n-jobs", type=int, default=2, help="parallel jobs with --launcher joblib (default 2)")


def run_study_command(body: Callable[[], Path]) -> int:
    """Run one of the study's commands: 0 and ``wrote PATH (N s in total)`` after ``body()`` returns the file it
    wrote; 1 and one ``error:`` line on stderr for bad input or a failed sweep; 130 on Ctrl-C."""
    start = time.perf_counter()
    try:
        written = body()
    except (ReproduceError, DataError, TuningError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print(f"wrote {written} ({time.perf_counter() - start:.0f} s in total)")
    return 0


def print_verdicts(report: Path) -> None:
    """The report's summary rows that carry a verdict (in bold), indented, on stdout."""
    for line in report.read_text().splitlines():
        if line.startswith("| ") and "**" in line:
            print("  " + line)
