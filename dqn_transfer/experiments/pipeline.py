"""The study's one pipeline, for any edition (:mod:`~dqn_transfer.experiments.edition`): tune -> pilot ->
budgets -> runs -> report, each stage into ``OUT``; an edition runs the stages it lists.

The pilot (:func:`run_pilots`) runs every experiment's sweep with the profile's pilot overrides; the edition's
budget rule on each job's pilot runs gives its budget, and each comparison group (the conditions compared with
each other) runs at the largest of its jobs' (:func:`pilot_budgets`). A group must be a product of values of
the swept keys, so that one multirun runs it (:func:`sweep_groups` checks). The full stage (:func:`run_full`)
exports every run's raw data with the manifest; the report is written from ``OUT``'s data alone.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from dqn_transfer.analysis.budget import Budget, BudgetRule, budgets_per_cell
from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.config import to_plain
from dqn_transfer.experiments import equivalence_report, hierarchical_report, paired_report
from dqn_transfer.experiments.cell_runs import CellMaps, cell_multiruns, maps_per_cell, read_maps
from dqn_transfer.experiments.edition import (
    BUDGETS_FILE,
    BUDGETS_TABLE,
    MAPS_FILE,
    PILOT_DIR,
    REPEAT_FILE,
    STAGES_FILE,
    Edition,
    Profile,
)
from dqn_transfer.experiments.raw_data import (
    DATA_DIR,
    MANIFEST,
    DataError,
    RunData,
    code_commit,
    data_digest,
    export_sweep,
    git_output,
    machine,
    read_data,
    read_manifest,
    write_data,
    write_json,
    write_manifest,
)
from dqn_transfer.experiments.sweeps import (
    RUNS_DIR,
    Multirun,
    ReproduceError,
    composed,
    count_jobs,
    quoted_path,
    read_stamp,
    run_multirun,
    swept_values,
)
from dqn_transfer.storage.run_dir import flatten

CHEST_REWARD = 100.0  # claim 1's maps have no optimum: its curves are counted in chests for the rule
REPORTS = {
    "paired": paired_report.write_report,
    "hierarchical": hierarchical_report.write_report,
    "equivalence": equivalence_report.write_report,
}


def rules_commit(edition: Edition) -> str:
    """The commit that registered the edition's rules: its tag's, else the rules file's last one."""
    if edition.rules_tag:
        return git_output("log", "-1", "--format=%h %cs", edition.rules_tag) or "not tagged"
    return git_output("log", "-1", "--format=%h %cs", "--", edition.rules) or "not committed"


def group_label(values: tuple[Any, ...]) -> str:
    """A group's directory name: its key's values joined (``sarsa-cooperative``; ``all`` for no key)."""
    return "-".join(str(v) for v in values) or "all"


@dataclass(frozen=True)
class Job:
    """One job of an experiment's sweep: its swept values, in Hydra's job order, and its composed config."""

    number: int
    values: dict[str, str]
    config: dict[str, Any]


@cache
def sweep_jobs(experiment: str) -> tuple[Job, ...]:
    """The jobs of ``experiment=<experiment>``'s sweep, numbered as Hydra's basic sweeper numbers them (the
    product of the swept values, the last key varying fastest); composed once per process (a config is
    composed in about 0.2 s)."""
    swept = swept_values(experiment)
    jobs = []
    for number, combination in enumerate(itertools.product(*swept.values())):
        values = dict(zip(swept, combination))
        jobs.append(Job(number, values, to_plain(composed(experiment, [f"{k}={v}" for k, v in values.items()]))))
    return tuple(jobs)


def sweep_groups(edition: Edition, name: str) -> dict[tuple[Any, ...], list[Job]]:
    """An experiment's jobs by comparison group; a ValueError if a group is not a product of swept values
    (one multirun could not run it alone)."""
    groups: dict[tuple[Any, ...], list[Job]] = {}
    for job in sweep_jobs(edition.experiment(name)):
        groups.setdefault(edition.comparisons[name].key(job.config), []).append(job)
    for key, jobs in groups.items():
        if math.prod(len(values) for values in _group_values(jobs).values()) != len(jobs):
            raise ValueError(f"{edition.experiment(name)}: group {group_label(key)} is not a product of swept values")
    return groups


def _group_values(jobs: Sequence[Job]) -> dict[str, list[str]]:
    """Each swept key's values among ``jobs``, in sweep order."""
    values: dict[str, list[str]] = {}
    for job in jobs:
        for key, value in job.values.items():
            if value not in values.setdefault(key, []):
                values[key].append(value)
    return values


def group_overrides(jobs: Sequence[Job]) -> list[str]:
    """The swept keys' overrides that make a multirun of exactly ``jobs``."""
    return [f"{key}={','.join(values)}" for key, values in _group_values(jobs).items()]


def cache_overrides(edition: Edition, name: str, out: Path) -> list[str]:
    """The sources or stages an experiment's jobs need, made once for every job inside ``OUT``."""
    if name not in edition.caches:
        return []
    key, subdir = edition.caches[name]
    return [f"{key}={quoted_path(out / subdir)}"]


# ------------------------------------------------------------------------------------------- pilot, budgets


def run_pilots(
    edition: Edition,
    names: Sequence[str],
    profile: str,
    out: Path,
    launcher: str,
    n_jobs: int,
    extra: Sequence[str] = (),
) -> Path:
    """Each experiment's pilot, then its raw data; returns ``OUT/pilot/data``. An edition with cells pilots
    its cells' conditions on their first maps (their runs stay among the cells' runs); another runs each
    experiment's sweep with the profile's pilot overrides."""
    settings = edition.profile(profile)
    data_dir = out / PILOT_DIR / DATA_DIR
    for name in names:
        if edition.cells:
            multiruns = cell_multiruns(edition, name, profile, out, maps=None)
            for multirun in multiruns:
                run_multirun(multirun, out, launcher, n_jobs, extra)
            write_data(data_dir / f"{name}.jsonl", export_multiruns(multiruns, out, name))
            continue
        experiment = edition.experiment(name)
        overrides = (*cache_overrides(edition, name, out / PILOT_DIR), *settings.pilot)
        sweep_dir = out / PILOT_DIR / RUNS_DIR / name
        stamp = {"experiment": experiment, "stage": "pilot", "profile": profile, "overrides": list(overrides)}
        jobs = len(sweep_jobs(experiment))
        multirun = Multirun(f"pilot-{name}", experiment, overrides, sweep_dir, jobs, stamp)
        run_multirun(multirun, out, launcher, n_jobs, extra)
        write_data(data_dir / f"{name}.jsonl", export_sweep(sweep_dir, name))
    return data_dir


def export_multiruns(multiruns: Sequence[Multirun], out: Path, name: str) -> list[RunData]:
    """The runs of experiment ``name``'s multiruns, each named by its path below ``OUT/runs/<name>/``."""
    runs: list[RunData] = []
    for multirun in multiruns:
        prefix = multirun.sweep_dir.relative_to(out / RUNS_DIR / name).as_posix()
        prefix = "" if prefix == "." else prefix + "/"
        runs += [dataclasses.replace(r, name=prefix + r.name) for r in export_sweep(multirun.sweep_dir, name)]
    return runs


def pilot_maps(edition: Edition, out: Path, names: Sequence[str], profile: Profile) -> list[CellMaps]:
    """Each cell's maps by the power rule, from the pilot's raw data of ``names`` alone."""
    runs = [run for name in names for run in read_data(out / PILOT_DIR / DATA_DIR / f"{name}.jsonl")]
    return maps_per_cell(edition, runs, profile.minimum, profile.cap)


@dataclass(frozen=True)
class CellBudget:
    """One job of a pilot: its swept values and the rule's budget for it."""

    experiment: str
    values: dict[str, str]
    runs: int
    budget: Budget


@dataclass(frozen=True)
class GroupBudget:
    """A comparison group: the largest of its jobs' budgets, which every job of the group is run with."""

    comparison: str
    key: tuple[Any, ...]
    cells: list[CellBudget]

    @property
    def budget(self) -> int:
        return max(cell.budget.budget for cell in self.cells)


def _rule_curve(run: RunData) -> Curve:
    """A pilot run's curve in the rule's units: its score; for a treasure map without an optimum (claim 1's
    one chest for two agents), its team return in chests."""
    steps, values = run.score_curve()
    no_optimum = run.optimal_return is None and run.config["env"].get("factory") is None
    return (steps, values / CHEST_REWARD) if no_optimum else (steps, values)


def _job_of(run: RunData, jobs: Sequence[Job], overridden: set[str]) -> Job:
    """The sweep job a pilot run belongs to: the one whose config it matches on every key in which the
    sweep's jobs differ, but the keys the pilot sets for every job (``overridden``, e.g. ``replicas.seeds``,
    which the methods set apart)."""
    flat = [flatten(job.config) for job in jobs]
    differing = {key for key in set().union(*flat) if len({f.get(key) for f in flat}) > 1} - overridden
    mine = flatten(run.config)
    matches = [job for job, f in zip(jobs, flat) if all(f.get(key) == mine.get(key) for key in differing)]
    if len(matches) != 1:
        raise DataError(f"pilot run {run.experiment}/{run.name} matches {len(matches)} jobs of the sweep, not one")
    return matches[0]


def pilot_rule(edition: Edition, profile: Profile) -> BudgetRule:
    """The edition's budget rule, with the profile's cap."""
    if edition.rule is None:
        raise ReproduceError(f"edition {edition.name} has no budget rule")
    return edition.rule if profile.rule_cap is None else dataclasses.replace(edition.rule, cap=profile.rule_cap)


def pilot_budgets(edition: Edition, pilot_data: Path, names: Sequence[str], profile: Profile) -> list[GroupBudget]:
    """The budgets from the pilot's raw data alone: each job's by the profile's rule, grouped by comparison."""
    overridden = {override.split("=", 1)[0] for override in profile.pilot}
    rule = pilot_rule(edition, profile)
    groups: dict[tuple[str, tuple[Any, ...]], list[CellBudget]] = {}
    for name in names:
        jobs = sweep_jobs(edition.experiment(name))
        by_job: dict[int, list[RunData]] = {}
        for run in read_data(pilot_data / f"{name}.jsonl"):
            by_job.setdefault(_job_of(run, jobs, overridden).number, []).append(run)
        missing = [job.values for job in jobs if job.number not in by_job]
        if missing:
            raise DataError(f"the pilot of {edition.experiment(name)} has no runs of {missing}")
        budgets = budgets_per_cell({n: [_rule_curve(r) for r in runs] for n, runs in by_job.items()}, rule)
        comparison = edition.comparisons[name]
        for job in jobs:
            cell = CellBudget(name, job.values, len(by_job[job.number]), budgets[job.number])
            groups.setdefault((comparison.name, comparison.key(job.config)), []).append(cell)
    return [GroupBudget(comparison, key, cells) for (comparison, key), cells in groups.items()]


def write_budgets(out: Path, groups: Sequence[GroupBudget], rule: BudgetRule) -> None:
    """``OUT/budgets.json`` (read by the full stage) and ``OUT/budgets.md`` (the table)."""
    record = {
        "rule": dataclasses.asdict(rule),
        "groups": [
            {
                "comparison": g.comparison,
                "key": list(g.key),
                "budget": g.budget,
                "cells": [
                    {
                        "experiment": c.experiment,
                        "values": c.values,
                        "runs": c.runs,
                        "converged_step": c.budget.converged_step,
                        "budget": c.budget.budget,
                        "capped": c.budget.capped,
                        "final_slope": round(c.budget.final_slope, 6),
                        "margin": round(c.budget.margin, 6),
                    }
                    for c in g.cells
                ],
            }
            for g in groups
        ],
    }
    write_json(out / BUDGETS_FILE, record)
    lines = [
        f"Budgets by the registered rule: the median over a job's pilot runs of the least-squares slope of their "
        f"last {rule.fraction:.0%} of evaluations (at least {rule.min_points}), in score per 1,000 steps; the "
        f"first step from which it stays below {rule.threshold:g}, times {rule.safety:g}, rounded up to a multiple "
        f"of {rule.round_to:,}, at most {rule.cap:,}; a comparison group runs at the largest of its jobs' budgets. "
        f"Margin: how close the converged step came to moving, the least distance to {rule.threshold:g} of the slopes "
        "that decided it (the last one not below it, and every one after); a slope that moves by less, on another "
        "CPU or in another library version, leaves the converged step where it is.",
        "",
        "| comparison | group | job | pilot runs | converged step | margin | job budget | group budget |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for g in groups:
        for c in g.cells:
            converged = "not converged" if c.budget.converged_step is None else f"{c.budget.converged_step:,}"
            job = " ".join(f"{k}={v}" for k, v in c.values.items())
            lines.append(
                f"| {g.comparison} | {group_label(g.key)} | {job} | {c.runs} | {converged} | {c.budget.margin:.4f} | "
                f"{c.budget.budget:,}{' (cap)' if c.budget.capped else ''} | {g.budget:,} |"
            )
    (out / BUDGETS_TABLE).write_text("\n".join(lines) + "\n")


def read_budgets(path: Path) -> dict[tuple[str, tuple[Any, ...]], int]:
    """Each comparison group's budget, from ``budgets.json``."""
    try:
        record = json.loads(path.read_text())
        return {(g["comparison"], tuple(g["key"])): int(g["budget"]) for g in record["groups"]}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ReproduceError(f"{path}: not a budgets file of the pilot stage ({err})") from err


# ------------------------------------------------------------------------------------------- the runs


def _multiruns(
    edition: Edition,
    name: str,
    profile: str,
    out: Path,
    budgets: dict[tuple[str, tuple[Any, ...]], int] | None,
    maps: dict[str, int] | None,
) -> list[Multirun]:
    """An experiment's multiruns: its cells' conditions on their maps, or each comparison group at its budget,
    or (neither) its file's sweep."""
    if maps is not None and any(cell.experiment == name for cell in edition.cells):
        return cell_multiruns(edition, name, profile, out, maps)
    experiment = edition.experiment(name)
    settings = (*cache_overrides(edition, name, out), *edition.profile(profile).run_overrides(name))
    if budgets is None:
        count = count_jobs(experiment, settings)
        stamp = {"experiment": experiment, "profile": profile, "overrides": list(settings), "jobs": count}
        return [Multirun(name, experiment, settings, out / RUNS_DIR / name, count, stamp)]
    multiruns = []
    for key, jobs in sweep_groups(edition, name).items():
        comparison = edition.comparisons[name].name
        if (comparison, key) not in budgets:
            raise ReproduceError(f"the budgets file has no budget for {comparison} {group_label(key)}")
        overrides = (*group_overrides(jobs), f"total_steps={budgets[(comparison, key)]}", *settings)
        stamp = {"experiment": experiment, "stage": "full", "profile": profile, "overrides": list(overrides)}
        sweep_dir = out / RUNS_DIR / name / group_label(key)
        multiruns.append(Multirun(f"{name}-{group_label(key)}", experiment, overrides, sweep_dir, len(jobs), stamp))
    return multiruns


def run_full(
    edition: Edition,
    names: Sequence[str],
    profile: str,
    out: Path,
    launcher: str | None,
    n_jobs: int,
    budgets_file: Path | None = None,
    extra: Sequence[str] = (),
) -> Path:
    """Each experiment's multiruns (none with ``launcher`` None: what ``OUT/runs/`` holds is exported), then
    its raw data and its record in the manifest (profile, code commit, machine, date, wall time, runs; beside
    the edition and its rules' commit); returns ``OUT/data``."""
    maps = {c.cell: c.maps for c in read_maps(out / MAPS_FILE).values()} if edition.cells else None
    budgets = read_budgets(budgets_file or out / BUDGETS_FILE) if edition.rule is not None else None
    data_dir = out / DATA_DIR
    made: dict[str, dict[str, Any]] = {}
    for name in names:
        multiruns = _multiruns(edition, name, profile, out, budgets, maps)
        done: list[Multirun] = []
        for multirun in multiruns:
            if launcher is not None:
                run_multirun(multirun, out, launcher, n_jobs, extra)
            if multirun.sweep_dir.is_dir():
                done.append(multirun)
        stamps = [read_stamp(m.sweep_dir) or {} for m in done]  # what the runs were made with, even if not by this call
        wall = sum(float(stamp.get("wall_seconds", 0.0)) for stamp in stamps)
        profiles = {str(stamp.get("profile", "unknown")) for stamp in stamps}
        runs = export_multiruns(done, out, name)
        if runs:
            write_data(data_dir / f"{name}.jsonl", runs)
            made[name] = {
                "profile": "/".join(sorted(profiles)),
                "commit": code_commit(),
                "machine": machine(),
                "date": _dt.date.today().isoformat(),
                "wall_seconds": round(wall, 1),
                "runs": len(runs),
            }
    if not made:
        raise ReproduceError(f"{out / RUNS_DIR} holds no runs of {', '.join(names)}: run the experiments first")
    previous = read_manifest(data_dir)  # experiments run before (--only, another session) keep their record
    write_manifest(
        data_dir,
        {
            "edition": edition.name,
            "rules_commit": rules_commit(edition),
            "experiments": {**previous.get("experiments", {}), **made},
        },
    )
    return data_dir


def record_stage(out: Path, stage: str, seconds: float) -> None:
    """Add an attempt of ``stage`` (its wall seconds) to ``OUT/stages.json``."""
    path = out / STAGES_FILE
    try:
        stages = json.loads(path.read_text())
    except (OSError, ValueError):
        stages = {}
    stages.setdefault(stage, []).append(round(seconds, 1))
    write_json(path, dict(sorted(stages.items())))


def record_repeat(results: Path, repeat: Path) -> Path:
    """``RESULTS/repeat.json`` from ``repeat``, a directory every stage ran into again: its stage times, the
    commits, dates and machines of its manifest, and its run records' digest (the report says whether they are
    the results' own)."""
    stages, manifest = repeat / STAGES_FILE, repeat / DATA_DIR / MANIFEST
    if not stages.is_file() or not manifest.is_file():
        raise ReproduceError(f"{repeat} is not a finished study: it needs {STAGES_FILE} and {DATA_DIR}/{MANIFEST}")
    made = read_manifest(repeat / DATA_DIR).get("experiments", {}).values()
    try:
        times = json.loads(stages.read_text())
    except ValueError:
        raise ReproduceError(f"{stages} is not valid JSON") from None
    path = results / REPEAT_FILE
    write_json(
        path,
        {
            **{key: sorted({str(record.get(key)) for record in made}) for key in ("commit", "date", "machine")},
            "stages": times,
            "data_sha256": data_digest(repeat / DATA_DIR),
        },
    )
    return path


def write_report(edition: Edition, results: Path, out: Path | None = None) -> Path:
    """``OUT/REPORT.md`` and its figures (``OUT`` = ``results`` by default) from ``results``' data alone, by
    the edition's analysis."""
    return REPORTS[edition.analysis](edition, results, results if out is None else out)
