"""The tuning protocol's analysis (docs/tuning.md), from its trials alone (``tuning.jsonl``).

One JSON line per trial of a search (a learner x knowledge-exchange method): the values it tried, its
objective (the mean over its tuning maps of each map's run objective) and each map's value, and the
search space it was drawn from. From these alone: each search's best trial (``tuned.yaml``), a Markdown
table, and the dose-response panels (objective against each searched key's value). A file that is not
such a record set is refused in one line naming the line at fault, before anything is written.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from dqn_transfer.analysis.plots import DosePanel
from dqn_transfer.storage.jsonl import json_lines

OBJECTIVES = ("final", "mean")  # the config's `objective`: the last evaluation's team return, or their mean


class TuningError(Exception):
    """Trials that cannot be analysed; the message is one line for the user."""


class Interval(NamedTuple):
    """A searched key's range, as its search space gave it (``tag(log, interval(low, high))``)."""

    low: float
    high: float
    log: bool


@dataclass(frozen=True)
class Trial:
    """One trial of one search: a run of replicas on the tuning maps with the trial's values."""

    learner: str
    method: str
    number: int  # Optuna's trial number, the sweep's job number
    params: dict[str, float]  # the searched keys' values (ints stay ints)
    objective: float  # what the sweeper maximised: the mean of per_map
    objective_kind: str  # final | mean (the config's objective)
    per_map: dict[int, float]  # map seed -> that map's objective (its seeds' mean)
    space: dict[str, Interval]

    @property
    def search(self) -> str:
        return f"{self.learner}_{self.method}"

    def record(self) -> dict[str, Any]:
        """The trial as one JSON object (map seeds as strings: JSON's keys are)."""
        return {
            "learner": self.learner,
            "method": self.method,
            "trial": self.number,
            "params": self.params,
            "objective": self.objective,
            "objective_kind": self.objective_kind,
            "per_map": {str(seed): value for seed, value in self.per_map.items()},
            "space": {key: bounds._asdict() for key, bounds in self.space.items()},
        }


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _field(record: dict[str, Any], name: str, kind: type | tuple[type, ...], where: str) -> Any:
    value = record.get(name)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise TuningError(f"{where}: '{name}' is missing or not of type {getattr(kind, '__name__', kind)}")
    return value


def _interval(key: str, value: Any, where: str) -> Interval:
    if not (isinstance(value, dict) and _is_number(value.get("low")) and _is_number(value.get("high"))):
        raise TuningError(f"{where}: space of '{key}' is not {{low, high, log}} with numbers")
    if not isinstance(value.get("log"), bool) or not value["low"] < value["high"]:
        raise TuningError(f"{where}: space of '{key}' needs low < high and log true or false")
    if value["log"] and value["low"] <= 0:
        raise TuningError(f"{where}: space of '{key}' is on a log scale but low is {value['low']} <= 0")
    return Interval(float(value["low"]), float(value["high"]), value["log"])


def trial_from_record(record: Any, where: str) -> Trial:
    """A trial from its JSON object; ``where`` (file:line) starts the one-line error of a bad one."""
    if not isinstance(record, dict):
        raise TuningError(f"{where}: not a JSON object")
    learner, method = _field(record, "learner", str, where), _field(record, "method", str, where)
    number = _field(record, "trial", int, where)
    params, space = _field(record, "params", dict, where), _field(record, "space", dict, where)
    per_map = _field(record, "per_map", dict, where)
    kind = record.get("objective_kind")
    if kind not in OBJECTIVES:
        raise TuningError(f"{where}: 'objective_kind' is {kind!r}, not one of {', '.join(OBJECTIVES)}")
    if not _is_number(record.get("objective")):
        raise TuningError(f"{where}: 'objective' is missing or not a finite number")
    if number < 0 or not space:
        raise TuningError(f"{where}: needs a trial number >= 0 and a non-empty search space")
    intervals = {key: _interval(key, value, where) for key, value in space.items()}
    if set(params) != set(intervals):
        raise TuningError(f"{where}: 'params' has keys {sorted(params)}, its search space {sorted(intervals)}")
    for key, value in params.items():
        bounds = intervals[key]
        if not _is_number(value) or not bounds.low <= value <= bounds.high:
            raise TuningError(f"{where}: {key}={value!r} is outside its search space [{bounds.low}, {bounds.high}]")
    if not per_map or not all(seed.isdigit() and _is_number(v) for seed, v in per_map.items()):
        raise TuningError(f"{where}: 'per_map' must map map seeds to finite numbers")
    return Trial(
        learner,
        method,
        number,
        dict(params),
        float(record["objective"]),
        kind,
        {int(seed): float(v) for seed, v in per_map.items()},
        intervals,
    )


def read_trials(path: str | os.PathLike) -> list[Trial]:
    """Every trial of ``path`` (``tuning.jsonl``), checked one by one and as searches (:func:`check_searches`)."""
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as err:
        raise TuningError(f"{path}: cannot read it ({err.strerror or err})") from None

    def bad_line(number: int) -> None:
        raise TuningError(f"{path}:{number}: not valid JSON") from None

    trials = [trial_from_record(record, f"{path}:{number}") for number, record in json_lines(lines, bad_line)]
    if not trials:
        raise TuningError(f"{path}: holds no trials")
    check_searches(trials, str(path))
    return trials


def check_searches(trials: Sequence[Trial], where: str) -> None:
    """The trials are searches of the protocol: each trial once, each search's trials of one space and one
    objective, the same objective and the same effort for every search: as many trials (the second edition's
    protocol), or as many per searched key (the third's)."""
    by_search: dict[str, list[Trial]] = {}
    for trial in trials:
        by_search.setdefault(trial.search, []).append(trial)
    for name, group in by_search.items():
        numbers = [t.number for t in group]
        if len(set(numbers)) != len(numbers):
            raise TuningError(f"{where}: search {name} has a trial number twice")
        if any(t.space != group[0].space for t in group):
            raise TuningError(f"{where}: the trials of search {name} were drawn from different search spaces")
    kinds = {t.objective_kind for t in trials}
    if len(kinds) > 1:
        raise TuningError(f"{where}: the trials optimise different objectives ({', '.join(sorted(kinds))})")
    counts = {name: len(group) for name, group in by_search.items()}
    per_key = {len(group) / len(group[0].space) for group in by_search.values()}
    if len(set(counts.values())) > 1 and len(per_key) > 1:
        listed = ", ".join(f"{name} {count}" for name, count in counts.items())
        raise TuningError(
            f"{where}: the searches have different numbers of trials ({listed}); each gets the same, or the same "
            "per searched key"
        )


def write_trials(path: Path, trials: Sequence[Trial]) -> None:
    path.write_text("".join(json.dumps(trial.record()) + "\n" for trial in trials))


def best_trials(trials: Sequence[Trial]) -> dict[tuple[str, str], Trial]:
    """Each search's ``(learner, method)`` -> its trial of the highest objective (the lowest trial number on
    a tie), in the order the searches first appear."""
    best: dict[tuple[str, str], Trial] = {}
    for trial in trials:
        key = (trial.learner, trial.method)
        current = best.get(key)
        if current is None or (trial.objective, -trial.number) > (current.objective, -current.number):
            best[key] = trial
    return best


def tuned_yaml(best: dict[tuple[str, str], Trial]) -> str:
    """``tuned.yaml``: learner -> method -> the best trial's values, as overrides take them."""
    tree: dict[str, dict[str, dict[str, float]]] = {}
    for (learner, method), trial in best.items():
        tree.setdefault(learner, {})[method] = trial.params
    kind = next(iter(best.values())).objective_kind
    header = (
        "# The best trial of each search of the tuning protocol (docs/tuning.md): learner -> method -> values.\n"
        f"# Objective: the {kind} team return, maximised on the tuning maps; written from tuning.jsonl.\n"
    )
    return header + yaml.safe_dump(tree, sort_keys=False)


def _value_text(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:.4g}"


def tuning_table(trials: Sequence[Trial], best: dict[tuple[str, str], Trial]) -> str:
    """Markdown: per search, its trials, the best trial's number, objective and values, and the median
    and range of its trials' objectives (how much the searched values matter)."""
    maps = sorted({seed for t in trials for seed in t.per_map})
    counts = {key: sum((t.learner, t.method) == key for t in trials) for key in best}
    per_key = {key: count // len(best[key].space) for key, count in counts.items()}
    effort = (
        f"each search {next(iter(counts.values()))} trials"
        if len(set(counts.values())) == 1
        else f"each search {next(iter(per_key.values()))} trials per searched key "
        f"({min(counts.values())} to {max(counts.values())})"
    )
    lines = [
        f"Objective: the {trials[0].objective_kind} team return over a run's evaluations, averaged over "
        f"{len(maps)} tuning maps (map seeds {maps[0]}..{maps[-1]}); {effort}.",
        "",
        "| learner | method | best trial | best objective | median | range | best values |",
        "| --- | --- | ---: | ---: | ---: | --- | --- |",
    ]
    spec = ".3f" if all(abs(t.objective) <= 1.0 for t in trials) else ".1f"  # a game scored in [0, 1]: LBF
    for (learner, method), trial in best.items():
        values = [t.objective for t in trials if (t.learner, t.method) == (learner, method)]
        chosen = ", ".join(f"`{key}={_value_text(value)}`" for key, value in trial.params.items())
        lines.append(
            f"| {learner} | {method} | {trial.number} | {trial.objective:{spec}} | {np.median(values):{spec}} | "
            f"{min(values):{spec}} .. {max(values):{spec}} | {chosen} |"
        )
    return "\n".join(lines) + "\n"


def sensitivity_panels(trials: Sequence[Trial], best: dict[tuple[str, str], Trial]) -> list[DosePanel]:
    """One panel per learner and searched key: each method's trials (value, objective), its best marked;
    a log axis where the key was searched on a log scale."""
    ranges: dict[tuple[str, str], Interval] = {}  # (learner, key) -> its searches' ranges, in order of appearance
    for trial in trials:
        for key, bounds in trial.space.items():
            seen = ranges.get((trial.learner, key), bounds)
            ranges[(trial.learner, key)] = Interval(
                min(seen.low, bounds.low), max(seen.high, bounds.high), seen.log and bounds.log
            )
    panels = []
    for (learner, key), bounds in ranges.items():
        series: dict[str, tuple[list[float], list[float]]] = {}
        for trial in trials:
            if trial.learner == learner and key in trial.params:
                xs, ys = series.setdefault(trial.method, ([], []))
                xs.append(trial.params[key])
                ys.append(trial.objective)
        marks = {m: (t.params[key], t.objective) for (lrn, m), t in best.items() if lrn == learner and key in t.params}
        panels.append(DosePanel(f"{learner}: {key}", key, bounds.log, (bounds.low, bounds.high), series, marks))
    return panels
