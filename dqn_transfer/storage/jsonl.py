"""Reading JSON-lines files (``metrics.jsonl``, ``tuning.jsonl``): one JSON value per line."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from typing import Any


def json_lines(lines: Sequence[str], bad_line: Callable[[int], None]) -> Iterator[tuple[int, Any]]:
    """Each non-blank line's number (from 1) and its parsed value.

    :param lines: the file's lines
    :param bad_line: called with the number of a line that is not JSON: it raises to refuse the file, or
        returns to skip the line (e.g. a last line cut short by a killed writer)
    """
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            value = json.loads(line)
        except json.JSONDecodeError:
            bad_line(number)
            continue
        yield number, value
