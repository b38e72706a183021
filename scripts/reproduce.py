#!/usr/bin/env python
"""Reproduce the study's three claims: run the sweeps, then write ``OUT/REPORT.md`` and figures.

    python scripts/reproduce.py --profile quick --out /tmp/repro_quick   # smoke run: minutes, 2-3 seeds
    python scripts/reproduce.py --profile full --out results/            # the evidence: >= 10 seeds
    python scripts/reproduce.py --out results/ --report-only             # re-analyse runs already there

``--help`` lists every option. The code is :mod:`dqn_transfer.cli.report` (also
``python -m dqn_transfer.cli.report``), :mod:`dqn_transfer.experiments` and :mod:`dqn_transfer.analysis`.
"""

import sys

from dqn_transfer.cli.report import main

if __name__ == "__main__":
    sys.exit(main())
