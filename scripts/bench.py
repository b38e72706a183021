#!/usr/bin/env python
"""The benchmark table: environment throughput, DQN training against Stable-Baselines3, per-step cost
as the team grows, and the cost of one gradient update.

    python scripts/bench.py [--quick] [--out outputs/bench.json] [--seed 0] [--repeats 3] [--threads 1]
    python scripts/bench.py --quick --repeats 1 --out /tmp/bench_quick.json   # a smoke run
    python scripts/bench.py --only env                                        # one section

``--help`` lists every option. The code is :mod:`dqn_transfer.cli.bench` (also ``dqn-transfer-bench``
and ``python -m dqn_transfer.cli.bench``) and :mod:`dqn_transfer.benchmark`.
"""

import sys

from dqn_transfer.cli.bench import main

if __name__ == "__main__":
    sys.exit(main())
