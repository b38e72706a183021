"""Stopping a run between two steps: SIGINT / SIGTERM become a request the loop honours with a checkpoint."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path
from typing import Any

log = logging.getLogger("dqn_transfer.train")


class Interrupted(Exception):
    """SIGINT or SIGTERM stopped the run between two steps, after it wrote its checkpoint there."""

    def __init__(self, signum: int, step: int, run_dir: Path) -> None:
        super().__init__(f"interrupted at step {step}")
        self.signum, self.step, self.run_dir = signum, step, Path(run_dir)

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 130 for SIGINT, 143 for SIGTERM."""
        return 128 + self.signum


class StopRequest:
    """Turns SIGINT (Ctrl-C) and SIGTERM (what SLURM sends before it kills a job) into a request the
    loop honours at the end of the step in progress, with a checkpoint that resumes exactly. A second
    Ctrl-C stops at once (``KeyboardInterrupt``). Signal handlers exist only in the main thread;
    elsewhere this is inert.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._previous = {signum: signal.signal(signum, self._handle) for signum in self.SIGNALS}
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)

    def asked(self) -> bool:
        """Whether a signal asked the run to stop."""
        return self.signum is not None

    def _handle(self, signum: int, frame: object) -> None:
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum
        log.warning(
            "%s received: stopping after this step, with a checkpoint%s",
            signal.Signals(signum).name,
            " (Ctrl-C again to stop at once)" if signum == signal.SIGINT else "",
        )
