"""Wall-clock and process-CPU stopwatches, for the trainer's own accounting and the benchmark, and
the facts about the machine a timing needs beside it."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path


def cpus_available() -> int:
    """The cores this process may run on (its affinity mask), else the machine's count."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


class Stopwatch:
    """Times ``with`` blocks; ``.wall`` and ``.cpu`` (seconds) add up over every block it timed.

    Wall time is what a user waits; CPU time (all threads of this process) is what the work costs,
    and is far less disturbed by other jobs on a shared machine.
    """

    def __init__(self) -> None:
        self.wall, self.cpu = 0.0, 0.0

    def __enter__(self) -> Stopwatch:
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.wall += time.perf_counter() - self._wall0
        self.cpu += time.process_time() - self._cpu0
