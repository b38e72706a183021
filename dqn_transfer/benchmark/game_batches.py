"""Joint steps per second of R games: R one-games in a loop
(:class:`~dqn_transfer.envs.game_batch.LoopedGames`) against the R games in one batch, as the training loop
steps them (:class:`~dqn_transfer.envs.game.TreasureHunts`): what batching the replicas saves.

Both play the same pre-drawn random actions on the same maps (8x8, 4 agents, 4 chests, complexity 0.1;
R replicas over 10 generated maps), each replica restarting its episode as it ends, in one process, one
after the other, ``repeats`` times each; a "joint step" is one step of one replica. Run it with
``python scripts/bench_batched_core.py``; not a section of ``dqn-transfer-bench`` (the suite's document
and tables are built for the learners' sections).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterator, Sequence
from typing import NamedTuple

import numpy as np

from dqn_transfer.envs.batch import GameBatch
from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts
from dqn_transfer.envs.game_batch import LoopedGames
from dqn_transfer.envs.maps import GridMap, generate_layout, parse_layout

SIZE, AGENTS, CHESTS, COMPLEXITY, DISTINCT_MAPS = 8, 4, 4, 0.1, 10
# A way to step the games: LoopedGames or TreasureHunts.of_games, built from the games and their generators.
BatchKind = Callable[[Sequence[TreasureHuntGame], Sequence[np.random.Generator]], GameBatch]


class GameBatchRates(NamedTuple):
    """The median joint steps/s of R replicas in one mode, each way."""

    mode: str
    replicas: int
    looped: float
    batched: float


def steps_per_second(kind: BatchKind, grid_maps: Sequence[GridMap], mode: str, actions: np.ndarray) -> float:
    """Joint steps/s of ``kind`` playing ``actions [steps, R, K]`` on ``grid_maps`` (one per replica)."""
    games = [TreasureHuntGame(m, mode=mode) for m in grid_maps]
    rngs = [np.random.default_rng(r) for r in range(len(games))]
    for game, rng in zip(games, rngs):
        game.reset(rng)
    batch = kind(games, rngs)
    start = time.perf_counter()
    for joint in actions:
        batch.reset(batch.step(joint).episode_end)
    return actions.shape[0] * actions.shape[1] / (time.perf_counter() - start)


def measure(
    replica_counts: Sequence[int], modes: Sequence[str], repeats: int, seconds: float
) -> Iterator[GameBatchRates]:
    """For each mode and R: both ways, ``repeats`` times, about ``seconds`` per measurement."""
    distinct = [
        parse_layout(generate_layout(SIZE, CHESTS, num_agents=AGENTS, complexity=COMPLEXITY, seed=seed))
        for seed in range(DISTINCT_MAPS)
    ]
    kinds: dict[str, BatchKind] = {"looped": LoopedGames, "batched": TreasureHunts.of_games}
    for mode in modes:
        for replicas in replica_counts:
            grid_maps = [distinct[r % DISTINCT_MAPS] for r in range(replicas)]
            probe = np.random.default_rng(0).integers(0, 4, size=(20, replicas, AGENTS))
            steps_per_second(LoopedGames, grid_maps, mode, probe)  # warm-up (imports, caches)
            rates: dict[str, list[float]] = {name: [] for name in kinds}
            for repeat in range(repeats):
                for name, kind in kinds.items():
                    first = steps_per_second(kind, grid_maps, mode, probe)
                    steps = max(20, int(seconds * first / replicas))
                    actions = np.random.default_rng(repeat + 1).integers(0, 4, size=(steps, replicas, AGENTS))
                    rates[name].append(steps_per_second(kind, grid_maps, mode, actions))
            yield GameBatchRates(
                mode, replicas, statistics.median(rates["looped"]), statistics.median(rates["batched"])
            )
