"""Wall-clock and process-CPU stopwatches, for the trainer's own accounting and the benchmark."""

from __future__ import annotations

import time


class Stopwatch:
    """Times ``with`` blocks; ``.wall`` and ``.cpu`` (seconds) add up over every block it timed.

    Wall time is what a user waits; CPU time (all threads of this process) is what the work costs,
    and is far less disturbed by other jobs on a shared machine.
    """

    def __init__(self) -> None:
        self.wall, self.cpu = 0.0, 0.0

    def __enter__(self) -> "Stopwatch":
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.wall += time.perf_counter() - self._wall0
        self.cpu += time.process_time() - self._cpu0
