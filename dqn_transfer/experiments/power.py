"""How many maps the second edition needs: a power analysis with the first edition's runs as the pilot.

The pilot's paired differences' map-level and run-level variances feed a simulation of the
hierarchical-bootstrap interval for studies of ``M`` maps x ``S`` seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from dqn_transfer.analysis.hierarchical import (
    MeanDifference,
    VarianceComponents,
    holm,
    maps_for_power,
    paired_mean_difference,
    variance_components,
)
from dqn_transfer.analysis.hierarchical import power as power_at
from dqn_transfer.experiments.claims import COOPERATIVE, NO_EXCHANGE, exchange_condition
from dqn_transfer.experiments.raw_data import DataError, RunData
from dqn_transfer.experiments.scoring import PRIMARY_LEARNER, final_score, group, learner, mode, score

EXCHANGES = ("best", "shared_replay")  # each against none; "best" is the verdict rules' primary comparison
EFFECTS = (0.05, 0.10)  # smallest effects of interest, in score units (fractions of the optimal return)
SEEDS = (2, 3, 5)  # seeds per map the second edition might run
TARGET_POWER = 0.8
ALPHA = 0.05
METRICS: dict[str, Callable[[RunData], float]] = {"final_score": final_score, "score": score}


@dataclass(frozen=True)
class PowerRow:
    """One comparison's pilot: its differences' mean with maps resampled, their variance components, and
    the fewest maps for :data:`TARGET_POWER` by (smallest effect, seeds per map); ``None``: more than
    :data:`~dqn_transfer.analysis.hierarchical.MAX_MAPS`. ``size`` is the false-positive rate of the
    interval at the pilot's own design (its maps x seeds) when there is no effect."""

    comparison: str
    difference: MeanDifference
    components: VarianceComponents
    maps_needed: dict[tuple[float, int], int | None]
    size: float


def differences_by_map(a: Sequence[RunData], b: Sequence[RunData], fn: Callable[[RunData], float]) -> list[np.ndarray]:
    """``fn(a) - fn(b)`` for every (map seed, seed) both conditions ran, one array per map (by map seed),
    its runs in seed order.

    :param a: condition X's runs.
    :param b: condition Y's runs (the control).
    :param fn: a run's value (a score).
    """
    by_unit = {r.unit: fn(r) for r in b}
    maps = group([r for r in a if r.unit in by_unit], lambda r: r.map_seed)
    return [np.array([fn(r) - by_unit[r.unit] for r in maps[m]]) for m in sorted(maps)]


def pilot_differences(runs: Sequence[RunData], exchange: str, fn: Callable[[RunData], float]) -> list[np.ndarray]:
    """The primary learner's cooperative runs with ``exchange`` minus those with none, paired, by map.

    :param runs: the hypothesis experiment's runs.
    :param exchange: the exchange condition set against none.
    :param fn: a run's value (a score).
    """
    cells = group([r for r in runs if (learner(r), mode(r)) == (PRIMARY_LEARNER, COOPERATIVE)], exchange_condition)
    if exchange not in cells or NO_EXCHANGE not in cells:
        raise DataError(f"the pilot has no {PRIMARY_LEARNER} cooperative runs with exchange {exchange} and none")
    return differences_by_map(cells[exchange], cells[NO_EXCHANGE], fn)


def power_rows(runs: Sequence[RunData], fn: Callable[[RunData], float], rng: np.random.Generator) -> list[PowerRow]:
    """One :class:`PowerRow` per exchange in :data:`EXCHANGES`.

    :param runs: the pilot: the hypothesis experiment's runs.
    :param fn: the value compared (a score of a run).
    :param rng: the bootstrap's and the simulations' stream.
    """
    rows = []
    for exchange in EXCHANGES:
        differences = pilot_differences(runs, exchange, fn)
        components = variance_components(differences)
        needed = {
            (effect, seeds): maps_for_power(
                effect, components.sigma_map, components.sigma_run, seeds, rng, TARGET_POWER, ALPHA
            )
            for effect in EFFECTS
            for seeds in SEEDS
        }
        pilot_seeds = round(components.n_runs / components.n_maps)
        size = power_at(0.0, components.sigma_map, components.sigma_run, components.n_maps, pilot_seeds, rng, ALPHA)
        difference = paired_mean_difference(differences, rng)
        rows.append(PowerRow(f"{exchange} - {NO_EXCHANGE}", difference, components, needed, size))
    return rows


def format_power_rows(rows: Sequence[PowerRow], metric: str) -> str:
    """The power table in Markdown; the p-values are Holm-adjusted over the table's rows as one family.

    :param rows: :func:`power_rows`' rows.
    :param metric: the compared value's name, for the heading.
    """
    maps_columns = [f"M, d={effect:g}, S={seeds}" for effect in EFFECTS for seeds in SEEDS]
    adjusted = holm([row.difference.p_value for row in rows])
    lines = [
        f"{PRIMARY_LEARNER}, {COOPERATIVE}: paired differences in {metric} (same map and seed). M: the fewest maps "
        f"for {TARGET_POWER:.0%} power (the hierarchical {1 - ALPHA:.0%} interval excludes 0) at smallest effect d "
        "with S seeds per map.",
        "",
        "| comparison | mean difference [95% CI, maps resampled] | p (Holm) | sigma_map | sigma_run | pilot "
        "| size at pilot's design | " + " | ".join(maps_columns) + " |",
        "|---|---:|---:|---:|---:|---:|---:|" + "---:|" * len(maps_columns),
    ]
    for row, p_holm in zip(rows, adjusted):
        c = row.components
        needed = [str(row.maps_needed[key]) if row.maps_needed[key] else "none" for key in row.maps_needed]
        lines.append(
            f"| {row.comparison} | {row.difference.estimate} | {p_holm:.3g} | {c.sigma_map:.4g} | {c.sigma_run:.4g} "
            f"| {c.n_maps} maps, {c.n_runs} runs | {row.size:.3f} | " + " | ".join(needed) + " |"
        )
    return "\n".join(lines)
