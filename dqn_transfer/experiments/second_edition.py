"""The study's second edition (``results/VERDICT_RULES.md``): its sweeps, the budget pilots, and the full runs
at each comparison's budget.

The stages after tuning (:mod:`dqn_transfer.experiments.tuning`), each into ``OUT``:

1. **pilot** (:func:`run_pilots`): every experiment of :data:`EXPERIMENTS` (``experiment=v2/<name>``) on the
   pilot maps (map seeds 2000.., one seed) for the budget rule's cap, into ``OUT/pilot/runs/<name>/``; its
   raw data into ``OUT/pilot/data/<name>.jsonl``;
2. **budgets** (:func:`pilot_budgets`): the registered :data:`RULE` on each job's pilot runs, and for each
   comparison group (the conditions compared with each other, :data:`COMPARISONS`) the largest of its jobs'
   budgets, so that conditions compared share a budget; ``OUT/budgets.json`` and ``OUT/budgets.md``,
   computed from the pilot's raw data alone;
3. **full** (:func:`run_full`): each comparison group as one Hydra multirun at its budget, into
   ``OUT/runs/<name>/<group>/``; every run's raw data into ``OUT/data/<name>.jsonl``.

A group is a set of an experiment's jobs (one per combination of its sweep's values) that share a budget;
it must be a product of values of the swept keys (so one multirun runs it), which :func:`sweep_groups`
checks.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import itertools
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser

from dqn_transfer.analysis.budget import Budget, BudgetRule, budgets_per_cell
from dqn_transfer.analysis.plots import flatten
from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.config import CONFIG_DIR, register_configs, to_plain
from dqn_transfer.experiments.raw_data import (
    DATA_DIR,
    DataError,
    RunData,
    code_commit,
    export_sweep,
    git_output,
    machine,
    read_data,
    read_manifest,
    write_data,
    write_manifest,
)
from dqn_transfer.experiments.sweeps import RUNS_DIR, Multirun, ReproduceError, quoted_path, run_multirun

GROUP = "v2"  # conf/experiment/v2/
EXPERIMENTS = ("hypothesis", "lbf_hypothesis", "claim1", "claim2", "transfer", "transfer_aware")
PILOT_DIR, BUDGETS_FILE, BUDGETS_TABLE = "pilot", "budgets.json", "budgets.md"
RULES_TAG = "study-v2-rules"  # results/VERDICT_RULES.md as registered before the runs

# The registered budget rule: the median run's slope over its last half of evaluations below 1% of the
# optimal return per 1,000 steps, 1.5 x that step, at most 32,000 steps.
RULE = BudgetRule(threshold=0.01, safety=1.5, cap=32_000, round_to=1_000, fraction=0.5, min_points=4)
PILOT_MAP_SEED = 2000  # the pilot maps 2000..2009: apart from the evaluation (0..) and tuning (1000..) maps
CHEST_REWARD = 100.0  # claim 1's maps have no optimum: its curves are counted in chests for the rule


@dataclass(frozen=True)
class Profile:
    """A stage's settings: the pilot's overrides and rule, the full runs' extra overrides."""

    pilot: tuple[str, ...]
    rule: BudgetRule
    full: tuple[str, ...]
    description: str


PROFILES = {
    "full": Profile(
        pilot=(
            f"env.map_seed={PILOT_MAP_SEED}",
            "replicas.maps=10",
            "replicas.seeds=1",
            f"total_steps={RULE.cap}",
            "eval_every=500",
        ),
        rule=RULE,
        full=(),
        description="the evidence: the registered design (results/VERDICT_RULES.md)",
    ),
    "quick": Profile(
        pilot=(
            f"env.map_seed={PILOT_MAP_SEED}",
            "replicas.maps=2",
            "replicas.seeds=1",
            "total_steps=2000",
            "eval_every=250",
            "agent.learning_starts=200",
            "transfer.pretrain_steps=500",
        ),
        rule=dataclasses.replace(RULE, cap=2000),
        full=("replicas.maps=2", "replicas.seeds=1", "agent.learning_starts=200", "transfer.pretrain_steps=500"),
        description="SMOKE RUN: 2 maps, one seed, budgets of at most 2,000 steps; it checks the pipeline, "
        "it is NOT evidence",
    ),
}


@dataclass(frozen=True)
class Comparison:
    """Which of an experiment's jobs share a budget: those with the same :attr:`key` of their config."""

    name: str  # the comparison (transfer and transfer_aware are one: their conditions are compared)
    key: Callable[[dict[str, Any]], tuple[Any, ...]]  # e.g. (learner, mode) for the hypothesis


def _learner(config: dict[str, Any]) -> tuple[Any, ...]:
    return (config["agent"]["algorithm"],)


COMPARISONS = {
    "hypothesis": Comparison("hypothesis", lambda c: (*_learner(c), c["env"]["mode"])),
    "lbf_hypothesis": Comparison("lbf_hypothesis", _learner),
    "claim1": Comparison("claim1", lambda c: ()),
    "claim2": Comparison("claim2", lambda c: (c["env"]["num_agents"], c["env"]["contention"])),  # m, contention
    "transfer": Comparison("transfer", _learner),
    "transfer_aware": Comparison("transfer", _learner),
}


def group_label(values: tuple[Any, ...]) -> str:
    """A group's directory name: its key's values joined (``sarsa-cooperative``; ``all`` for no key)."""
    return "-".join(str(v) for v in values) or "all"


@dataclass(frozen=True)
class Job:
    """One job of an experiment's sweep: its swept values, in Hydra's job order, and its composed config."""

    number: int
    values: dict[str, str]
    config: dict[str, Any]


def _composed(experiment: str, overrides: Sequence[str] = (), hydra_config: bool = False) -> Any:
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(
            config_name="config", overrides=[f"experiment={experiment}", *overrides], return_hydra_config=hydra_config
        )


@cache
def sweep_jobs(name: str) -> tuple[Job, ...]:
    """The jobs of ``experiment=v2/<name>``'s sweep, numbered as Hydra's basic sweeper numbers them (the
    product of the swept values, the last key varying fastest); composed once per process (a config is
    composed in about 0.2 s)."""
    experiment = f"{GROUP}/{name}"
    sweeper = _composed(experiment, hydra_config=True).hydra.sweeper
    params = {key: str(value) for key, value in (sweeper.params or {}).items()}
    parser = OverridesParser.create()
    swept = {
        override.get_key_element(): (
            list(override.sweep_string_iterator())
            if override.is_sweep_override()
            else [override.get_value_element_as_str()]
        )
        for override in parser.parse_overrides([f"{k}={v}" for k, v in params.items()])
    }
    jobs = []
    for number, combination in enumerate(itertools.product(*swept.values())):
        values = dict(zip(swept, combination))
        jobs.append(Job(number, values, to_plain(_composed(experiment, [f"{k}={v}" for k, v in values.items()]))))
    return tuple(jobs)


def sweep_groups(name: str) -> dict[tuple[Any, ...], list[Job]]:
    """An experiment's jobs by comparison group; a ValueError if a group is not a product of swept values
    (one multirun could not run it alone)."""
    groups: dict[tuple[Any, ...], list[Job]] = {}
    for job in sweep_jobs(name):
        groups.setdefault(COMPARISONS[name].key(job.config), []).append(job)
    for key, jobs in groups.items():
        size = 1
        for values in _group_values(jobs).values():
            size *= len(values)
        if size != len(jobs):
            raise ValueError(f"v2/{name}: group {group_label(key)} is not a product of swept values")
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


def _cache_overrides(name: str, out: Path) -> list[str]:
    """The transfer sources, pretrained once for every job that needs them, inside ``OUT``."""
    return [f"transfer.cache_dir={quoted_path(out / 'pretrained')}"] if name.startswith("transfer") else []


def _expected_jobs(name: str) -> int:
    return len(sweep_jobs(name))


def run_pilots(names: Sequence[str], profile: str, out: Path, launcher: str, n_jobs: int) -> Path:
    """Stage 2: each experiment's sweep on the pilot maps for the cap, then its raw data; returns
    ``OUT/pilot/data``."""
    settings = PROFILES[profile]
    data_dir = out / PILOT_DIR / DATA_DIR
    for name in names:
        overrides = (*_cache_overrides(name, out / PILOT_DIR), *settings.pilot)
        sweep_dir = out / PILOT_DIR / RUNS_DIR / name
        stamp = {"experiment": f"{GROUP}/{name}", "stage": "pilot", "profile": profile, "overrides": list(overrides)}
        run_multirun(
            Multirun(f"pilot-{name}", f"{GROUP}/{name}", overrides, sweep_dir, _expected_jobs(name), stamp),
            out,
            launcher,
            n_jobs,
        )
        write_data(data_dir / f"{name}.jsonl", export_sweep(sweep_dir, name))
    return data_dir


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


def pilot_budgets(pilot_data: Path, names: Sequence[str], profile: Profile) -> list[GroupBudget]:
    """Stage 3 from the pilot's raw data alone: each job's budget by the profile's rule, grouped by
    comparison."""
    overridden = {override.split("=", 1)[0] for override in profile.pilot}
    groups: dict[tuple[str, tuple[Any, ...]], list[CellBudget]] = {}
    for name in names:
        jobs = sweep_jobs(name)
        by_job: dict[int, list[RunData]] = {}
        for run in read_data(pilot_data / f"{name}.jsonl"):
            by_job.setdefault(_job_of(run, jobs, overridden).number, []).append(run)
        missing = [job.values for job in jobs if job.number not in by_job]
        if missing:
            raise DataError(f"the pilot of v2/{name} has no runs of {missing}")
        budgets = budgets_per_cell({n: [_rule_curve(r) for r in runs] for n, runs in by_job.items()}, profile.rule)
        comparison = COMPARISONS[name]
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
    out.mkdir(parents=True, exist_ok=True)
    (out / BUDGETS_FILE).write_text(json.dumps(record, indent=1) + "\n")
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


def run_full(names: Sequence[str], profile: str, out: Path, budgets_file: Path, launcher: str, n_jobs: int) -> Path:
    """Stage 4: each comparison group as one multirun at its budget, then each experiment's raw data and its
    record in the manifest (profile, code commit, machine, date, wall time, runs; beside the rules' tag commit);
    returns ``OUT/data``."""
    budgets = read_budgets(budgets_file)
    settings = PROFILES[profile]
    data_dir = out / DATA_DIR
    made: dict[str, dict[str, Any]] = {}
    for name in names:
        runs: list[RunData] = []
        wall = 0.0
        for key, jobs in sweep_groups(name).items():
            comparison = COMPARISONS[name].name
            if (comparison, key) not in budgets:
                raise ReproduceError(f"{budgets_file} has no budget for {comparison} {group_label(key)}")
            overrides = (
                *group_overrides(jobs),
                f"total_steps={budgets[(comparison, key)]}",
                *_cache_overrides(name, out),
                *settings.full,
            )
            sweep_dir = out / RUNS_DIR / name / group_label(key)
            stamp = {"experiment": f"{GROUP}/{name}", "stage": "full", "profile": profile, "overrides": list(overrides)}
            multirun = Multirun(f"{name}-{group_label(key)}", f"{GROUP}/{name}", overrides, sweep_dir, len(jobs), stamp)
            wall += run_multirun(multirun, out, launcher, n_jobs)
            runs += [
                dataclasses.replace(run, name=f"{group_label(key)}/{run.name}") for run in export_sweep(sweep_dir, name)
            ]
        write_data(data_dir / f"{name}.jsonl", runs)
        made[name] = {
            "profile": profile,
            "commit": code_commit(),
            "machine": machine(),
            "date": _dt.date.today().isoformat(),
            "wall_seconds": round(wall, 1),
            "runs": len(runs),
        }
    previous = read_manifest(data_dir)  # experiments run before (--only, another session) keep their record
    write_manifest(
        data_dir,
        {
            "rules_commit": git_output("log", "-1", "--format=%h %cs", RULES_TAG) or "not tagged",
            "experiments": {**previous.get("experiments", {}), **made},
        },
    )
    return data_dir
