"""How much the agents of a map contend for chests: its contention beside the oracle's matching.

See docs/game.md. :meth:`~dqn_transfer.envs.maps.GridMap.contention` is the fraction of agents whose
nearest chest (the shortest trap-free path from its start, the lower chest index on equal length) is
also another agent's; ``env.contention`` chooses generated maps by it. Beside it,
:func:`map_contention` gives the fraction of agents whose chest in the oracle's minimum-total matching
(:meth:`~dqn_transfer.evaluation.bounds.Walker.matching`, docs/bounds.md) is not their nearest: how
often the best team sends an agent past its nearest chest.

    python -m dqn_transfer.cli.contention study_fixed/m2 study_fixed/m6 --maps 30
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from dqn_transfer.enums import Contention
from dqn_transfer.envs.maps import GridMap, resolve_map
from dqn_transfer.envs.settings import MAP_KEYS
from dqn_transfer.evaluation.bounds import Walker
from dqn_transfer.timing import Stopwatch


@dataclass(frozen=True)
class MapContention:
    """One map's contention, and how often its optimum sends an agent past its nearest chest."""

    contention: float  # agents whose nearest chest is another's too, as a fraction of the agents
    not_nearest: float  # agents matched by the oracle to a chest other than their nearest (or to none)


def map_contention(grid_map: GridMap) -> MapContention:
    """``grid_map``'s :class:`MapContention`, every agent at its start and every chest full. With more agents
    than chests, an agent the matching leaves without a chest counts as not at its nearest."""
    n = grid_map.size
    cells = np.array([r * n + c for r, c in grid_map.starts])
    matched = Walker(grid_map).matching(
        cells, np.ones(grid_map.num_agents, dtype=bool), np.ones(grid_map.num_treasures, dtype=bool)
    )
    not_nearest = matched != grid_map.nearest_chests()
    return MapContention(grid_map.contention(), float(not_nearest.mean()))


@dataclass(frozen=True)
class ContentionRow:
    """The maps of one env setting and one ``env.contention``, over map seeds."""

    env: str  # what the settings are called (an env option's name)
    contention: Contention
    maps: int
    mean_contention: float
    mean_not_nearest: float
    generation_cpu: float  # process CPU seconds to generate the maps (resolve_map), all of them


def contention_rows(
    env: str, settings: Mapping[str, Any], map_seeds: Sequence[int], contentions: Iterable[Contention] = Contention
) -> list[ContentionRow]:
    """One :class:`ContentionRow` per contention, for the map keys of ``settings`` on ``map_seeds`` (its own
    ``map_seed`` and ``contention`` replaced)."""
    given = {key: settings.get(key) for key in MAP_KEYS if key not in ("map_seed", "contention")}
    rows = []
    for contention in contentions:
        with Stopwatch() as stopwatch:
            maps = [resolve_map(**given, map_seed=seed, contention=contention) for seed in map_seeds]
        measured = [map_contention(grid_map) for grid_map in maps]
        rows.append(
            ContentionRow(
                env,
                contention,
                len(maps),
                float(np.mean([m.contention for m in measured])),
                float(np.mean([m.not_nearest for m in measured])),
                stopwatch.cpu,
            )
        )
    return rows


def contention_table(rows: Sequence[ContentionRow]) -> str:
    """``rows`` as a Markdown table."""
    lines = [
        "| env | contention | maps | mean contention | optimal chest not nearest | generation, CPU s |",
        "|---|---|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r.env} | {r.contention.value} | {r.maps} | {r.mean_contention:.3f} | {r.mean_not_nearest:.3f} "
        f"| {r.generation_cpu:.2f} |"
        for r in rows
    ]
    return "\n".join(lines)
