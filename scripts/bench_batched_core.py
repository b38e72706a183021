"""Joint steps per second of R games: the one-game core in a Python loop vs the batched core.

    python scripts/bench_batched_core.py [--replicas 10 100 1000] [--repeats 3] [--seconds 1.0]

Both play the same pre-drawn random actions on the same maps (8x8, 4 agents, 4 chests, complexity 0.1;
R replicas over 10 generated maps), episodes restarting as they end (the loop resets a finished game,
the batched core auto-resets), in one process, one after the other, ``--repeats`` times each; a
"joint step" is one step of one replica. Prints the median rate of each and their ratio.

A script rather than a section of ``dqn-transfer-bench`` (the suite's records and tables are built for
the learners' sections); its figures set ``envs.game_batch.BATCHED_CORE_MIN_REPLICAS``, below which the
training loop steps the one-game core in a loop.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from dqn_transfer.envs.batched import batch_maps, reset, step
from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.maps import generate_layout, parse_layout

SIZE, AGENTS, CHESTS, COMPLEXITY, DISTINCT_MAPS = 8, 4, 4, 0.1, 10


def loop_rate(grid_maps, mode: str, actions: np.ndarray) -> float:
    games = [TreasureHuntGame(m, mode=mode) for m in grid_maps]
    rngs = [np.random.default_rng(r) for r in range(len(games))]
    for game, rng in zip(games, rngs):
        game.reset(rng)
    start = time.perf_counter()
    for joint in actions:
        for game, rng, row in zip(games, rngs, joint):
            if game.done:
                game.reset(rng)
            game.step(row)
    return actions.shape[0] * actions.shape[1] / (time.perf_counter() - start)


def batched_rate(grid_maps, mode: str, actions: np.ndarray) -> float:
    maps = batch_maps(grid_maps, mode=mode, auto_reset=True)
    rngs = [np.random.default_rng(r) for r in range(len(grid_maps))]
    state, _ = reset(maps, rngs)
    start = time.perf_counter()
    for joint in actions:
        state, _ = step(maps, state, joint, rngs)
    return actions.shape[0] * actions.shape[1] / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicas", type=int, nargs="+", default=[10, 100, 1000])
    parser.add_argument("--modes", nargs="+", default=["cooperative", "deliberative"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=1.0, help="about this long per measurement")
    args = parser.parse_args()
    distinct = [
        parse_layout(generate_layout(SIZE, CHESTS, num_agents=AGENTS, complexity=COMPLEXITY, seed=seed))
        for seed in range(DISTINCT_MAPS)
    ]
    print(f"{SIZE}x{SIZE}, {AGENTS} agents, {CHESTS} chests, random actions; median of {args.repeats} repeats")
    print(f"{'mode':>13} {'R':>5} {'loop steps/s':>13} {'batched steps/s':>16} {'ratio':>7}")
    for mode in args.modes:
        for replicas in args.replicas:
            grid_maps = [distinct[r % DISTINCT_MAPS] for r in range(replicas)]
            probe = np.random.default_rng(0).integers(0, 4, size=(20, replicas, AGENTS))
            loop_rate(grid_maps, mode, probe)  # warm-up (imports, caches) and a first estimate
            rates = {"loop": [], "batched": []}
            for repeat in range(args.repeats):
                for name, measure in (("loop", loop_rate), ("batched", batched_rate)):
                    first = measure(grid_maps, mode, probe)
                    steps = max(20, int(args.seconds * first / replicas))
                    actions = np.random.default_rng(repeat + 1).integers(0, 4, size=(steps, replicas, AGENTS))
                    rates[name].append(measure(grid_maps, mode, actions))
            loop, batched = statistics.median(rates["loop"]), statistics.median(rates["batched"])
            print(f"{mode:>13} {replicas:>5} {loop:>13,.0f} {batched:>16,.0f} {batched / loop:>6.1f}x", flush=True)


if __name__ == "__main__":
    main()
