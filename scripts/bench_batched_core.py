"""Joint steps per second of R games: R one-games in a loop vs the R games as one batch.

    python scripts/bench_batched_core.py [--replicas 1 4 8 100] [--repeats 3] [--seconds 1.0]

What it measures and how: :mod:`dqn_transfer.benchmark.game_batches`. Prints the median rate of each
and their ratio.
"""

from __future__ import annotations

import argparse

from dqn_transfer.benchmark.game_batches import AGENTS, CHESTS, SIZE, measure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicas", type=int, nargs="+", default=[1, 4, 8, 100])
    parser.add_argument("--modes", nargs="+", default=["cooperative", "deliberative"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=1.0, help="about this long per measurement")
    args = parser.parse_args()
    print(f"{SIZE}x{SIZE}, {AGENTS} agents, {CHESTS} chests, random actions; median of {args.repeats} repeats")
    print(f"{'mode':>13} {'R':>5} {'loop steps/s':>13} {'batched steps/s':>16} {'ratio':>7}")
    for row in measure(args.replicas, args.modes, args.repeats, args.seconds):
        ratio = row.batched / row.looped
        print(f"{row.mode:>13} {row.replicas:>5} {row.looped:>13,.0f} {row.batched:>16,.0f} {ratio:>6.1f}x", flush=True)


if __name__ == "__main__":
    main()
