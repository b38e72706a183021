"""Compiled kernels: numba's ``njit`` with its on-disk cache where one can be written.

A kernel is compiled the first time a process calls it (about 10 s for the game's rules, 16 s with the
tabular learners', on 2 cores) and, with the cache, loaded from disk by every later process (a second).
The cache lives in ``kernels-<fingerprint>`` under ``NUMBA_CACHE_DIR`` if it is set, else under the
package's ``__pycache__``, else (a read-only install) under the user's cache directory. The fingerprint
is a hash of every package file that holds a kernel: numba checks only the calling kernel's own file
for changes, while a kernel's compiled code includes the kernels it calls from other files, so any
change to one of them starts a new cache (and older ones are removed). Where no directory can be
written, kernels are compiled in every process instead, after one notice.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba
from numba.misc.appdirs import AppDirs

log = logging.getLogger(__name__)

F = TypeVar("F", bound=Callable[..., Any])
PACKAGE = Path(__file__).parent


def _writable(directory: Path) -> bool:
    """Whether a file can be created in ``directory`` (made if missing)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            return True
    except OSError:
        return False


def kernels_fingerprint() -> str:
    """A hash of the package's files that hold kernels (their paths and contents)."""
    digest = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_bytes()
        if any(decorator in text for decorator in (b"@kernel", b"@array_kernel")):
            digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0" + text)
    return digest.hexdigest()[:16]


def cache_directory() -> Path | None:
    """Where this package's compiled kernels are kept (None: nowhere writable); older caches beside it
    are removed."""
    configured = os.environ.get("NUMBA_CACHE_DIR")
    bases = (
        [Path(configured)]
        if configured
        else [PACKAGE / "__pycache__", Path(AppDirs(appname="dqn_transfer", appauthor=False).user_cache_dir)]
    )
    name = f"kernels-{kernels_fingerprint()}"
    for base in bases:
        if _writable(base / name):
            for older in base.glob("kernels-*"):
                if older.name != name:
                    shutil.rmtree(older, ignore_errors=True)
            return base / name
    return None


CACHE_DIR = cache_directory()
if CACHE_DIR is None:
    log.warning(
        "no writable cache directory for the compiled kernels (set NUMBA_CACHE_DIR to one): "
        "they are compiled again in every process, 10-16 s at start-up"
    )
else:
    numba.config.CACHE_DIR = str(CACHE_DIR)  # type: ignore[attr-defined]  # read whenever numba caches a kernel
CACHE = CACHE_DIR is not None
# Nothing compiled yet for this code: the first run compiles (what the trainer says before it does).
FIRST_COMPILE = CACHE_DIR is None or not any(CACHE_DIR.rglob("*.nbi"))


def kernel(function: F) -> F:
    """``function`` compiled by numba in nopython mode, cached on disk when possible."""
    return numba.njit(cache=CACHE)(function)  # type: ignore[return-value]


def array_kernel(function: F) -> F:
    """A :func:`kernel` with numpy's float semantics: a division by zero gives inf or nan, as numpy's does,
    instead of raising ``ZeroDivisionError``. Without that check in every division LLVM can vectorise the
    loops (``error_model="numpy"``): for elementwise passes over float arrays."""
    return numba.njit(cache=CACHE, error_model="numpy")(function)  # type: ignore[return-value]
