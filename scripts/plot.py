#!/usr/bin/env python
"""Plot the evaluation curves of run directories, each condition as its mean and 95% band over seeds.

    python scripts/plot.py RUN_DIR [RUN_DIR ...] --out fig.png [--metric team_return]
    python scripts/plot.py outputs/multirun/claim1/<stamp> --out curves.png   # a sweep folder: every run below it

``--help`` lists every option. The code is :mod:`dqn_transfer.cli.plot` (also
``python -m dqn_transfer.cli.plot``) and :mod:`dqn_transfer.analysis.plots`.
"""

import sys

from dqn_transfer.cli.plot import main

if __name__ == "__main__":
    sys.exit(main())
