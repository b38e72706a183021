"""What every console script does around its ``main``, a parser whose errors are one line, and how the study's
commands end (what they wrote, or one ``error:`` line)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from dqn_transfer.experiments.raw_data import DataError
from dqn_transfer.experiments.sweeps import ReproduceError


def exit_with(main: Callable[[], int]) -> None:
    """Exit with ``main()``'s code, quietly when the reader of stdout goes away (``... | head``: the
    reader left; not an error worth a traceback)."""
    try:
        sys.exit(main())
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at interpreter exit
        sys.exit(0)


class OneLineErrors(argparse.ArgumentParser):
    """An argument parser whose bad input is one ``error:`` line on stderr and exit code 2, without the usage
    block."""

    def error(self, message: str) -> NoReturn:
        print(f"error: {message}", file=sys.stderr)
        sys.exit(2)


def run_study_command(body: Callable[[], Path]) -> int:
    """Run one of the study's commands: 0 and ``wrote PATH (N s in total)`` after ``body()`` returns the file it
    wrote; 1 and one ``error:`` line on stderr for bad input or a failed sweep; 130 on Ctrl-C."""
    start = time.perf_counter()
    try:
        written = body()
    except (ReproduceError, DataError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print(f"wrote {written} ({time.perf_counter() - start:.0f} s in total)")
    return 0
