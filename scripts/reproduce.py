#!/usr/bin/env python
"""The study's first edition: run its sweeps, keep their raw data in ``OUT/data/``, write ``OUT/REPORT.md`` and figures.

    python scripts/reproduce.py --profile quick --out /tmp/study     # smoke run: about a minute, NOT evidence
    python scripts/reproduce.py --profile full --out results/v1      # the evidence, 9 min on 2 cores
    python scripts/reproduce.py results/v1 --out /tmp/report          # the report again from its data/

``--help`` lists every option. The code is :mod:`dqn_transfer.cli.report` (also
``python -m dqn_transfer.cli.report``), :mod:`dqn_transfer.experiments` and :mod:`dqn_transfer.analysis`.
"""

import sys

from dqn_transfer.cli.report import main

if __name__ == "__main__":
    sys.exit(main())
