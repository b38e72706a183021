"""Runs in marl-eval's JSON layout (InstaDeep's ``id-marl-eval``, the MARL field's evaluation tools).

marl-eval reads one nested dictionary::

    {environment: {task: {algorithm: {"seed_N": {"step_0": {"step_count": int, metric: [float], ...},
                                                  ...,
                                                  "step_k": {...},
                                                  "absolute_metrics": {metric: [float], ...}}}}}}

What each level is for our runs (docs/integrations.md):

- **environment**: ``treasurehunt`` (the caller may name another, e.g. one per experiment of the study:
  marl-eval compares algorithms within an environment, over its tasks).
- **task**: the game a run is scored on, ``<mode>-<K>agents-<size>x<size>-map<map_seed>`` (``layout<hash>``
  for a fixed layout; ``-contention_<c>`` after it unless ``env.contention`` is ``any``): the maps are the
  tasks rliable stratifies by, as in this project's statistics.
- **algorithm**: the learner and its condition, ``<agent.algorithm>[+transfer][+curriculum][+exchange_<x>]
  [+shared]``; where two runs of one task and seed would still share a name, the config keys that tell
  them apart are appended (``;key=value``, never a comma: marl-eval refuses commas in names).
- **seed_N**: the run's ``seed``; **step_i**: its i-th evaluation, ``step_count`` its env step.
- metrics: each evaluation's means over its greedy episodes, as one-element lists (``metrics.jsonl``
  keeps the means, not the episodes), and **absolute_metrics**: each metric's mean over the last
  ``final_tail`` of the run's evaluations (this project's final performance, not marl-eval's
  10x-episodes re-evaluation of the best policy).
- per-agent metrics: each agent's mean return as a metric of its own beside the team's,
  ``agent_<i>_return`` (:func:`agent_return_metric`), as BenchMARL's marl-eval files name a group's
  return ``<group>_return``: marl-eval's layout has no per-agent level, and its processing takes the
  mean of every entry of a step, so each entry is a list of numbers.

marl-eval lower-cases every key; the keys written here are lower case already. Its processing needs the
same tasks, algorithms, seeds and number of evaluations throughout an environment:
:func:`layout_problems` says where an export falls short of that.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from dqn_transfer.analysis.transfer_metrics import asymptotic_performance
from dqn_transfer.enums import Contention
from dqn_transfer.storage.run_dir import flatten

ENVIRONMENT = "treasurehunt"
ABSOLUTE = "absolute_metrics"
# Config keys that place a run in a task and a seed, never used to tell algorithms apart.
_PLACEMENT_KEYS = {
    "seed",
    "env.map_seed",
    "replicas.seeds",
    "replicas.maps",
    "replicas.workers",
    "resume",
    "progress",
    "threads",
}


@dataclass(frozen=True)
class EvaluatedRun:
    """One run's evaluations, whatever they were read from (a run directory, the study's raw data)."""

    name: str  # where it came from, for messages
    config: Mapping[str, Any]  # the composed Hydra config
    steps: Sequence[int]
    metrics: Mapping[str, Sequence[float]]  # one value per step


def agent_return_metric(agent: int) -> str:
    """The metric name of one agent's return, ``agent_<i>_return``.

    :param agent: the agent's index in its team.
    """
    return f"agent_{agent}_return"


def game_name(config: Mapping[str, Any]) -> str:
    """The game a run played: ``treasurehunt``, or another game's module name (``env.factory``,
    docs/your_own_environment.md), lower-case."""
    factory = config["env"].get("factory")
    return str(factory).split(":")[0].rsplit(".", 1)[-1].lower() if factory else ENVIRONMENT


def task_name(config: Mapping[str, Any]) -> str:
    """``<mode>-<K>agents-<size>x<size>-map<map_seed>[-contention_<c>]`` (``layout<hash8>`` for a fixed
    layout; ``env.contention`` named unless ``any``, whose maps are another of the seed's); for another game
    (``env.factory``), ``<its module>-map<map_seed>``."""
    env = config["env"]
    if env.get("factory"):  # another game: the instance is its map seed
        return f"{game_name(config)}-map{env.get('map_seed') or 0}"
    layout = env.get("layout") or env.get("layout_file")
    contention = Contention(env.get("contention") or Contention.any.value)
    where = (
        f"layout{hashlib.sha1(str(layout).encode()).hexdigest()[:8]}" if layout else f"map{env.get('map_seed') or 0}"
    )
    if contention is not Contention.any:
        where += f"-contention_{contention.value}"
    return f"{env['mode']}-{env['num_agents']}agents-{env['size']}x{env['size']}-{where}".lower()


def algorithm_name(config: Mapping[str, Any]) -> str:
    """``<agent.algorithm>[+transfer[_own][+chest_aware]][+curriculum][+exchange_<x>][+shared[+id]][+vdn]``."""
    agent, transfer = config["agent"], config.get("transfer") or {}
    name = str(agent["algorithm"])
    if transfer.get("enabled"):
        name += "+transfer_own" if transfer.get("source_task") == "per_agent" else "+transfer"
        if transfer.get("chest_aware"):
            name += "+chest_aware"
    if (config.get("curriculum") or {}).get("stages"):
        name += "+curriculum"
    if transfer.get("exchange", "none") != "none":
        name += f"+exchange_{transfer['exchange']}"
    if agent.get("share_parameters"):
        name += "+shared+id" if agent.get("agent_id_input") else "+shared"
    if agent.get("mixer", "none") != "none":
        name += f"+{agent['mixer']}"
    return name.lower()


def _names(runs: Sequence[EvaluatedRun]) -> list[tuple[str, str, str]]:
    """(task, algorithm, seed key) of each run; a name shared by two runs of one task and seed takes the
    config keys that differ among the runs of that name."""
    base = [(task_name(r.config), algorithm_name(r.config), f"seed_{r.config['seed']}") for r in runs]
    flats = [flatten(r.config, partial(json.dumps, sort_keys=True)) for r in runs]
    slots: dict[tuple[str, str, str], list[int]] = {}
    for i, key in enumerate(base):
        slots.setdefault(key, []).append(i)
    # the keys that tell apart the runs of one place, per algorithm: appended to each of its runs' names
    telling: dict[str, set[str]] = {}
    for (_, algorithm, _), members in slots.items():
        if len(members) > 1:
            keys = set().union(*(flats[j] for j in members)) - _PLACEMENT_KEYS
            telling.setdefault(algorithm, set()).update(k for k in keys if len({flats[j].get(k) for j in members}) > 1)
    names = []
    for i, (task, algorithm, seed) in enumerate(base):
        told = sorted(telling.get(algorithm, ()))
        suffix = ";".join(f"{k}={flats[i].get(k, 'null')}".replace(",", " ").replace('"', "") for k in told)
        names.append((task, f"{algorithm};{suffix}".lower() if suffix else algorithm, seed))
    return names


def _values(values: Iterable[float]) -> list[float]:
    return [float(v) if math.isfinite(v) else float("nan") for v in values]


def marl_eval_tree(
    runs: Sequence[EvaluatedRun], final_tail: float, environment: str = ENVIRONMENT
) -> dict[str, dict[str, Any]]:
    """``{environment: {task: {algorithm: {seed_N: {step_i: ..., absolute_metrics: ...}}}}}`` (see the
    module's docstring). Raises ``ValueError`` if there are no runs or two runs get the same place."""
    if not runs:
        raise ValueError("no runs to export")
    tree: dict[str, Any] = {}
    placed: dict[tuple[str, str, str], str] = {}
    for run, (task, algorithm, seed) in zip(runs, _names(runs)):
        if (task, algorithm, seed) in placed:
            raise ValueError(
                f"{run.name} and {placed[task, algorithm, seed]} have the same task, algorithm and seed "
                f"({task}, {algorithm}, {seed}): export them separately"
            )
        placed[task, algorithm, seed] = run.name
        entry: dict[str, Any] = {}
        for i, step in enumerate(run.steps):
            entry[f"step_{i}"] = {"step_count": int(step), **{m: [float(v[i])] for m, v in run.metrics.items()}}
        steps = np.asarray(run.steps, dtype=np.float64)
        entry[ABSOLUTE] = {
            m: _values([asymptotic_performance((steps, np.asarray(v, dtype=np.float64)), final_tail)])
            for m, v in run.metrics.items()
        }
        tree.setdefault(task, {}).setdefault(algorithm, {})[seed] = entry
    return {environment.lower(): tree}


def layout_problems(tree: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Where ``tree`` falls short of what marl-eval's processing assumes within an environment: every task
    with the same algorithms, every (task, algorithm) with the same seeds, every run with the same number
    of evaluations and the same metrics. One line per shortfall; [] if none."""
    problems = []
    for environment, tasks in tree.items():
        algorithms = {task: sorted(algos) for task, algos in tasks.items()}
        if len({tuple(a) for a in algorithms.values()}) > 1:
            problems.append(f"{environment}: the tasks do not all have the same algorithms")
        seeds = {(t, a): tuple(sorted(runs)) for t, algos in tasks.items() for a, runs in algos.items()}
        if len(set(seeds.values())) > 1:
            problems.append(f"{environment}: the tasks' algorithms do not all have the same seeds")
        shapes = {
            (len(entry), tuple(sorted(entry[ABSOLUTE])))
            for algos in tasks.values()
            for runs in algos.values()
            for entry in runs.values()
        }
        if len(shapes) > 1:
            problems.append(f"{environment}: the runs do not all have the same number of evaluations and metrics")
    return problems
