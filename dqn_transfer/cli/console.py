"""What every console script does around its ``main``."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable


def exit_with(main: Callable[[], int]) -> None:
    """Exit with ``main()``'s code, quietly when the reader of stdout goes away (``... | head``: the
    reader left; not an error worth a traceback)."""
    try:
        sys.exit(main())
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at interpreter exit
        sys.exit(0)
