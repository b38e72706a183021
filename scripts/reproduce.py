#!/usr/bin/env python
"""The first edition's runs, their data and report (the command its committed report names).

    python scripts/reproduce.py --profile full --out results/v1      # the evidence, 9 min on 2 cores

The same as ``python -m dqn_transfer.cli.study full --edition v1 ...`` (:mod:`dqn_transfer.cli.study`, which
runs every edition: ``conf/edition/``).
"""

import sys

from dqn_transfer.cli.study import main

if __name__ == "__main__":
    sys.exit(main(["full", "--edition", "v1", *sys.argv[1:]]))
