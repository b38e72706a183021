"""What every console script does around its ``main``, and a parser whose errors are one line (light: the
training entry point imports it; the study's commands' endings are :mod:`~dqn_transfer.cli.study_console`)."""

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


def error_line(body: Callable[[], int], errors: tuple[type[Exception], ...], code: int) -> int:
    """``body()``'s exit code; ``code`` and one ``error:`` line on stderr when it raises one of ``errors``.

    :param body: the command's work, returning its exit code
    :param errors: the exceptions that are bad input, whose message is the line
    :param code: the exit code of bad input
    """
    try:
        return body()
    except errors as err:
        print(f"error: {err}", file=sys.stderr)
        return code


def docstring_parser(doc: str, prog: str | None = None) -> OneLineErrors:
    """A :class:`OneLineErrors` parser that a command module's docstring describes: its first paragraph above
    the options, the rest below them as written.

    :param doc: the command module's ``__doc__``
    :param prog: the program's name in the usage line (None: argparse's, from ``sys.argv[0]``)
    """
    summary, details = doc.split("\n\n", 1)
    return OneLineErrors(
        prog=prog, description=summary, formatter_class=argparse.RawDescriptionHelpFormatter, epilog=details
    )
