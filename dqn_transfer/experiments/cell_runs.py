"""The runs of an edition with cells (the third's, ``conf/edition/v3.yaml``): each condition of a cell at its
tuned values, on the cell's maps in two chunks: the pilot's first maps, then the rest up to the power rule's M.

A cell (:class:`~dqn_transfer.experiments.edition.Cell`) is the jobs of one experiment's sweep with given
swept values (``env=study/m6``); a job's ``method`` option names its condition (``sarsa_best``: ``best``).
Each (cell, condition, chunk) is one multirun of one job, its replicas the chunk's maps x the seeds, into
``OUT/runs/<experiment>/<cell>/<condition>/maps-<first>-<last>/``, so its runs' names in the raw data say
their cell and condition. The tuned values come from ``OUT/tuning/<cell's tuning>/tuned.yaml`` as overrides:
the values tuned for this edition never replace ``conf/tuned/``, which the second edition runs with.

The power rule (:func:`maps_per_cell`) reads the pilot's raw data alone: for each primary comparison of a cell
(a method against ``none``), the variance components of its paired differences in normalised AUC and the
fewest maps with 80% power at the SESOI at Holm's strictest level; a cell runs the most of them, between its
minimum and its cap.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from omegaconf import OmegaConf

from dqn_transfer.analysis.equivalence import ALPHA, POWER_TARGET, maps_for_power, power
from dqn_transfer.analysis.hierarchical import variance_components
from dqn_transfer.config import TrainConfig
from dqn_transfer.experiments.edition import MAPS_FILE, MAPS_TABLE, TUNING_DIR, Cell, Edition
from dqn_transfer.experiments.equivalence_claims import SESOI, auc_value
from dqn_transfer.experiments.power import differences_by_map
from dqn_transfer.experiments.raw_data import RunData, write_json
from dqn_transfer.experiments.sweeps import RUNS_DIR, Multirun, ReproduceError, composed, swept_values
from dqn_transfer.experiments.tuning import SEARCHES, TUNED_FILE
from dqn_transfer.training.plan import memory_estimate
from dqn_transfer.training.resources import Estimate, gigabytes

CONTROL = "none"  # every comparison of a cell is a condition against the team without exchange
LEARNERS = tuple(dict.fromkeys(search.learner for search in SEARCHES))


def condition_of(method_option: str) -> tuple[str, str]:
    """``(learner, condition)`` of a ``method=`` option: ``double_dqn_shared_replay`` is
    ``("double_dqn", "shared_replay")``."""
    for learner in sorted(LEARNERS, key=len, reverse=True):
        if method_option.startswith(learner + "_"):
            return learner, method_option[len(learner) + 1 :]
    raise ReproduceError(f"method={method_option}: not <learner>_<method> with a learner of {', '.join(LEARNERS)}")


def cell_of(run: RunData) -> str:
    """The cell of a run of a cell's experiment (the first part of its name)."""
    return run.name.split("/", 1)[0]


def condition_of_run(run: RunData) -> str:
    """The condition of a run of a cell's experiment (the second part of its name)."""
    return run.name.split("/", 2)[1]


@dataclass(frozen=True)
class CellJob:
    """One condition of a cell: the swept values of its job in the experiment's sweep."""

    cell: Cell
    values: dict[str, str]

    @property
    def learner(self) -> str:
        return condition_of(self.values["method"])[0]

    @property
    def condition(self) -> str:
        return condition_of(self.values["method"])[1]


def cell_jobs(edition: Edition, cell: Cell, swept: dict[str, list[str]]) -> list[CellJob]:
    """The conditions of ``cell``: the jobs of its experiment's sweep (``swept``: each key's values) whose
    values include the cell's ``where``."""
    keys = list(swept)
    combinations = (dict(zip(keys, values)) for values in itertools.product(*swept.values()))
    jobs = [CellJob(cell, values) for values in combinations if cell.holds(cell.experiment, values)]
    if not jobs or "method" not in keys:
        raise ReproduceError(
            f"cell {cell.name}: experiment {edition.experiment(cell.experiment)} sweeps no method there"
        )
    return jobs


def tuned_overrides(edition: Edition, job: CellJob, out: Path) -> list[str]:
    """The overrides of a condition's tuned values: its method's, or for a control the method it controls
    (``edition.tuned_as``), from ``OUT/tuning/<cell's tuning>/tuned.yaml``."""
    path = out / TUNING_DIR / job.cell.tuning / TUNED_FILE
    try:
        tuned = yaml.safe_load(path.read_text())
        values = tuned[job.learner][edition.tuned_as.get(job.condition, job.condition)]
    except (OSError, yaml.YAMLError) as err:
        raise ReproduceError(f"{path}: cannot read the tuned values ({err}); run the tune stage first") from None
    except (KeyError, TypeError):
        raise ReproduceError(f"{path}: no tuned values of {job.learner} x {job.condition}") from None
    return [f"{key}={value!r}" for key, value in sorted(values.items())]


def chunk_overrides(edition: Edition, job: CellJob, out: Path, first: int, count: int, profile: str) -> list[str]:
    """The overrides of one condition of a cell on maps ``first .. first + count - 1``: its swept values, its
    tuned values, the maps, and the profile's settings."""
    return [
        *(f"{key}={value}" for key, value in job.values.items()),
        *tuned_overrides(edition, job, out),
        f"env.map_seed={first}",
        f"replicas.maps={count}",
        *edition.profile(profile).run_overrides(job.cell.experiment),
    ]


def chunk_multirun(
    edition: Edition, job: CellJob, out: Path, first: int, count: int, profile: str, stage: str
) -> Multirun:
    """The multirun of one condition of a cell on maps ``first .. first + count - 1`` (``stage``: the one
    that runs it, pilot or full), with the profile's settings. Its checkpoints are deleted once it has
    finished: the study reads its runs' metrics, and a Double DQN run's last checkpoint holds its replay."""
    experiment = edition.experiment(job.cell.experiment)
    overrides = tuple(chunk_overrides(edition, job, out, first, count, profile))
    chunk = f"maps-{first}-{first + count - 1}"
    sweep_dir = out / RUNS_DIR / job.cell.experiment / job.cell.name / job.condition / chunk
    stamp = {"experiment": experiment, "stage": stage, "profile": profile, "overrides": list(overrides)}
    return Multirun(
        f"{job.cell.name}-{job.condition}-{chunk}", experiment, overrides, sweep_dir, 1, stamp, keep_checkpoints=False
    )


def map_chunks(
    edition: Edition, job: CellJob, out: Path, first: int, count: int, profile: str
) -> list[tuple[int, int]]:
    """Maps ``first .. first + count - 1`` of a condition as ``(first, count)`` ranges: as few and as equal as
    keep each one's estimated peak memory (:func:`~dqn_transfer.training.plan.memory_estimate`) within
    ``edition.chunk_gigabytes``. A replica trains as the lone run of its (map, seed) in any batch, so how the
    maps are split changes no result."""
    if edition.chunk_gigabytes is None:
        return [(first, count)]
    composed_config = composed(
        edition.experiment(job.cell.experiment), chunk_overrides(edition, job, out, first, count, profile)
    )
    config: TrainConfig = OmegaConf.to_object(composed_config)  # type: ignore[assignment]

    def need(maps: int) -> Estimate | None:
        return memory_estimate(dataclasses.replace(config, replicas=dataclasses.replace(config.replicas, maps=maps)))

    budget, one_map = edition.chunk_gigabytes * 1e9, need(1)
    if one_map is None:  # another game's runs are not estimated
        return [(first, count)]
    if one_map.total > budget:
        raise ReproduceError(
            f"cell {job.cell.name}, {job.condition}: one map's replicas need about {gigabytes(one_map.total)} "
            f"({one_map.parts()}), more than the edition's chunk_gigabytes={edition.chunk_gigabytes:g}"
        )
    parts = next(n for n in range(1, count + 1) if need(-(-count // n)).total <= budget)  # type: ignore[union-attr]
    size, extra = divmod(count, parts)
    starts = [first + i * size + min(i, extra) for i in range(parts + 1)]
    return [(start, end - start) for start, end in zip(starts, starts[1:])]


def cell_multiruns(edition: Edition, name: str, profile: str, out: Path, maps: dict[str, int] | None) -> list[Multirun]:
    """The multiruns of experiment ``name``'s cells: each condition on the pilot's maps, then (``maps``: each
    cell's number, from the power rule) on the rest of its maps, each range in chunks (:func:`map_chunks`)."""
    pilot = edition.profile(profile).pilot_maps or edition.pilot_maps
    swept = swept_values(edition.experiment(name))
    multiruns = []
    for cell in (cell for cell in edition.cells if cell.experiment == name):
        ranges = [("pilot", 0, pilot)]
        if maps is not None and maps[cell.name] > pilot:
            ranges.append(("full", pilot, maps[cell.name] - pilot))
        for job in cell_jobs(edition, cell, swept):
            for stage, first, count in ranges:
                multiruns += [
                    chunk_multirun(edition, job, out, start, size, profile, stage)
                    for start, size in map_chunks(edition, job, out, first, count, profile)
                ]
    return multiruns


# ------------------------------------------------------------------------------------------- the power rule


@dataclass(frozen=True)
class ComparisonPower:
    """One primary comparison's variance components in the pilot and the maps it needs."""

    condition: str
    sigma_map: float
    sigma_run: float
    needed: int  # the fewest maps with the target power, or the cap + 1 if even the cap has less
    power_at_maps: float  # its power at the cell's maps


@dataclass(frozen=True)
class CellMaps:
    """A cell's number of maps by the power rule, and why."""

    cell: str
    maps: int
    seeds: int
    alpha: float  # Holm's strictest level: ALPHA / the family's size
    comparisons: list[ComparisonPower]


def by_cell(runs: Sequence[RunData]) -> dict[str, dict[str, list[RunData]]]:
    """Runs of cells' experiments by cell, then by condition."""
    cells: dict[str, dict[str, list[RunData]]] = {}
    for run in runs:
        cells.setdefault(cell_of(run), {}).setdefault(condition_of_run(run), []).append(run)
    return cells


def maps_per_cell(
    edition: Edition, pilot: Sequence[RunData], minimum: int | None = None, cap: int | None = None
) -> list[CellMaps]:
    """Each cell's maps from the pilot's runs by the power rule; ``minimum`` and ``cap`` replace every cell's
    own (a profile's)."""
    result = []
    cells = by_cell(pilot)
    for cell in edition.cells:
        by_condition = cells.get(cell.name, {})
        if CONTROL not in by_condition:
            raise ReproduceError(f"the pilot holds no runs of cell {cell.name}'s {CONTROL}: run the pilot stage")
        primary = [c for c in by_condition if c != CONTROL and c not in edition.tuned_as]
        seeds = max(len({run.seed for run in by_condition[CONTROL]}), 1)
        alpha = ALPHA / max(len(primary), 1)
        least = cell.minimum if minimum is None else minimum
        most = cell.cap if cap is None else cap

        needs = []
        for condition in primary:
            try:
                components = variance_components(
                    differences_by_map(by_condition[condition], by_condition[CONTROL], auc_value)
                )
            except ValueError as err:
                raise ReproduceError(f"cell {cell.name}, the pilot of {condition} against {CONTROL}: {err}") from None
            sigma_map, sigma_run = components.sigma_map, components.sigma_run
            at_cap = power(SESOI, sigma_map, sigma_run, most, seeds, alpha)
            needed = most + 1 if at_cap < POWER_TARGET else maps_for_power(SESOI, sigma_map, sigma_run, seeds, alpha)
            needs.append((condition, sigma_map, sigma_run, needed))
        maps = min(most, max([least, *(n for *_, n in needs)]))
        comparisons = [
            ComparisonPower(c, sm, sr, n, power(SESOI, sm, sr, maps, seeds, alpha)) for c, sm, sr, n in needs
        ]
        result.append(CellMaps(cell.name, maps, seeds, alpha, comparisons))
    return result


def write_maps(out: Path, cells: Sequence[CellMaps]) -> None:
    """``OUT/maps.json`` (read by the full stage and the report) and ``OUT/maps.md`` (the table)."""
    write_json(out / MAPS_FILE, {"cells": [_plain(c) for c in cells]})
    lines = [
        f"Maps per cell by the registered power rule: from the pilot's paired differences in normalised AUC, "
        f"each primary comparison's fewest maps whose two-sided t-test at Holm's strictest level has "
        f"{POWER_TARGET:.0%} power at the SESOI {SESOI:g}; a cell runs the most of them, between its minimum and its "
        "cap.",
        "",
        "| cell | comparison | sigma_map | sigma_run | maps needed | power at the cell's maps | cell's maps |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for cell in cells:
        for c in cell.comparisons:
            needed = (
                f"> {c.needed - 1}" if c.needed > max(cell.maps, 2) and c.power_at_maps < POWER_TARGET else c.needed
            )
            lines.append(
                f"| {cell.cell} | {c.condition} − none | {c.sigma_map:.4f} | {c.sigma_run:.4f} | {needed} | "
                f"{c.power_at_maps:.0%} | {cell.maps} |"
            )
    (out / MAPS_TABLE).write_text("\n".join(lines) + "\n")


def _plain(cell: CellMaps) -> dict[str, Any]:
    return {
        "cell": cell.cell,
        "maps": cell.maps,
        "seeds": cell.seeds,
        "alpha": cell.alpha,
        "comparisons": [
            {
                "condition": c.condition,
                "sigma_map": round(c.sigma_map, 6),
                "sigma_run": round(c.sigma_run, 6),
                "needed": c.needed,
                "power_at_maps": round(c.power_at_maps, 4),
            }
            for c in cell.comparisons
        ],
    }


def read_maps(path: Path) -> dict[str, CellMaps]:
    """Each cell's maps, from ``maps.json``."""
    try:
        record = json.loads(path.read_text())
        return {
            c["cell"]: CellMaps(
                c["cell"],
                int(c["maps"]),
                int(c["seeds"]),
                float(c["alpha"]),
                [ComparisonPower(**p) for p in c["comparisons"]],
            )
            for c in record["cells"]
        }
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ReproduceError(f"{path}: not a maps file of the pilot stage ({err}); run the pilot stage") from err
