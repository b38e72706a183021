"""What every console script does around its ``main``, and a parser whose errors are one line."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from typing import NoReturn


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
