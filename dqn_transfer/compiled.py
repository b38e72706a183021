"""Compiled kernels: numba's ``njit`` with its on-disk cache where one can be written.

A kernel is compiled the first time a process calls it (a few seconds for the game's rules) and, with
the cache, loaded from disk by every later process. numba keeps the cache in the package's
``__pycache__`` or, where that is read-only (an installed package), in the user's cache directory
(``NUMBA_CACHE_DIR`` overrides both). Where none of them can be written, kernels are compiled in every
process instead, after one notice.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba
from numba.misc.appdirs import AppDirs

log = logging.getLogger(__name__)

F = TypeVar("F", bound=Callable[..., Any])


def _writable(directory: Path) -> bool:
    """Whether a file can be created in ``directory`` (made if missing)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            return True
    except OSError:
        return False


def cache_directory() -> Path | None:
    """Where numba will write this package's compiled kernels (None: nowhere writable)."""
    configured = os.environ.get("NUMBA_CACHE_DIR")
    candidates = (
        [Path(configured)]
        if configured
        else [Path(__file__).parent / "__pycache__", Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)]
    )
    return next((directory for directory in candidates if _writable(directory)), None)


CACHE = cache_directory() is not None
if not CACHE:
    log.warning(
        "no writable cache directory for the compiled kernels (set NUMBA_CACHE_DIR to one): "
        "they are compiled again in every process, a few seconds at start-up"
    )


def kernel(function: F) -> F:
    """``function`` compiled by numba in nopython mode, cached on disk when possible."""
    return numba.njit(cache=CACHE)(function)  # type: ignore[return-value]
