#!/usr/bin/env python
"""Fixed-seed reference runs: record them before a refactor, again after, and show 0 files different.

    python scripts/reference_runs.py OUT              # runs the set into OUT/, writes OUT/DIGESTS.txt
    python scripts/reference_runs.py --compare A B    # the files whose digests differ (exit 1 if any)

What the set holds and how a file is digested: :mod:`dqn_transfer.benchmark.reference_runs`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dqn_transfer.benchmark.reference_runs import ReferenceRunError, compare, record


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, nargs="?", help="a new directory for the recording")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"), help="two recordings' directories")
    args = parser.parse_args()
    if args.compare:
        return compare(*args.compare)
    if args.out is None:
        parser.error("give OUT or --compare A B")
    try:
        record(args.out.resolve())
    except ReferenceRunError as err:
        sys.exit(str(err))
    return 0


if __name__ == "__main__":
    sys.exit(main())
