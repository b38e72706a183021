#!/usr/bin/env python
"""The torch engine's gradient step, hand-written backward against autograd, side by side in one process.

    python scripts/time_dqn_backward.py [--repeats 7] [--steps 200] [--replicas 10]

The variants and the shapes: :mod:`dqn_transfer.benchmark.dqn_backward`. Prints the median and the best µs per
gradient step of each.
"""

from __future__ import annotations

import argparse
import statistics

import torch

from dqn_transfer.benchmark.dqn_backward import HIDDEN, B, K, measure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--replicas", type=int, default=10, help="R")
    args = parser.parse_args()
    torch.set_num_threads(1)  # the engine's default (``threads``)
    times = measure(args.replicas, args.repeats, args.steps)
    print(f"R={args.replicas} K={K} B={B} hidden={HIDDEN}, {args.repeats} x {args.steps} steps, µs per step:")
    for name, values in times.items():
        print(f"  {name:14s} median {statistics.median(values):8.0f}   best {min(values):8.0f}")


if __name__ == "__main__":
    main()
