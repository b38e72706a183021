"""The study's raw data: every run's evaluations, compact, one JSON line per run (:class:`RunData`).

``OUT/data/<experiment>.jsonl`` holds the runs, ``OUT/data/manifest.json`` how they were made. The report reads
these files and nothing else, so it can be regenerated, and every number in it recomputed, without the run
directories (checkpoints, TensorBoard logs), which stay out of the repository.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import platform
import shutil
import subprocess
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dqn_transfer.analysis.runs import load_runs, read_metrics, source_steps
from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.envs.maps import GridMap, optimal_team_return, resolve_map
from dqn_transfer.envs.settings import MAP_KEYS
from dqn_transfer.storage.run_dir import natural_key
from dqn_transfer.timing import cpu_model, cpus_available

DATA_DIR = "data"
# Where a report's text says its data are: true wherever the report is written (--out DIR writes the
# report and its figures there; the data stay in the results directory), so the bytes are the same.
DATA_SOURCE = (
    f"`{DATA_DIR}/` of the results directory from which `dqn-transfer-report RESULTS [--out DIR]` writes this report"
)
REPO_DIR = Path(__file__).resolve().parents[2]  # the checkout the package runs from
MANIFEST = "manifest.json"
SMOKE_MARK = "SMOKE RUN - not evidence"  # a report's figures' watermark when any of its data is not the full profile's
# The evaluation metrics kept per step (metrics.jsonl has more: episode lengths, wall times, epsilon).
METRICS = ("team_return", "success_rate", "trap_rate", "after_clear_rate", "return_after_clear")
CACHE_DIRS = ("transfer", "curriculum")  # the config sections whose cache_dir a record names, not locates
DIGITS = 6  # significant digits kept: evaluations are means of a few episodes' integer returns


class DataError(Exception):
    """Raw data that cannot be read or used; the message is one user-facing line."""


@dataclass(frozen=True)
class RunData:
    """One run's evaluations and the config that tells its condition."""

    experiment: str
    name: str  # <job>/<replica> in the sweep directory
    config: dict[str, Any]
    steps: tuple[int, ...]
    metrics: dict[str, tuple[float, ...]]
    steps_before: int  # env steps spent on its transfer source(s) before its own step 0
    optimal_return: float | None  # None: more agents than chests (no clean optimum), or another game

    @property
    def seed(self) -> int:
        return int(self.config["seed"])

    @property
    def map_seed(self) -> int:
        return int(self.config["env"].get("map_seed") or 0)

    @property
    def unit(self) -> tuple[int, int]:
        """(map seed, seed): runs of two conditions with the same unit share their map, initial values
        and exploration noise, so differences between conditions are paired by it."""
        return self.map_seed, self.seed

    def curve(self, metric: str = "team_return") -> Curve:
        if metric not in self.metrics:
            raise DataError(f"run {self.experiment}/{self.name} has no {metric!r} evaluations")
        return np.asarray(self.steps, dtype=np.float64), np.asarray(self.metrics[metric], dtype=np.float64)

    def score_curve(self) -> Curve:
        """Team return as a fraction of the map's optimal return (1 = every agent took its own chest by
        a shortest path); the raw team return where the map has no clean optimum, and for another game
        (``env.factory``) its own team return (LBF's is normalised: 1 when all food is loaded)."""
        steps, values = self.curve()
        return (steps, values / self.optimal_return) if self.optimal_return else (steps, values)

    def to_json(self) -> dict[str, Any]:
        return {
            "experiment": self.experiment,
            "name": self.name,
            "steps_before": self.steps_before,
            "optimal_return": self.optimal_return,
            "steps": list(self.steps),
            "metrics": {k: list(v) for k, v in self.metrics.items()},
            "config": self.config,
        }


def _rounded(value: float) -> float:
    return float(f"{value:.{DIGITS}g}") if math.isfinite(value) else value


def map_optimum(config: dict[str, Any]) -> float | None:
    """The optimal team return of a run's map, from its config (the map rebuilt as the trainer did); None for
    another game (``env.factory``), which has no treasure map: its runs are scored on its own team return."""
    env = config["env"]
    if env.get("factory") is not None:
        return None
    grid = _run_map(tuple(env.get(key) for key in MAP_KEYS))
    return optimal_team_return(
        grid, grid.num_agents, float(env.get("treasure_reward", 100.0)), float(env.get("step_reward", -1.0))
    )


@functools.cache
def _run_map(settings: tuple[Any, ...]) -> GridMap:
    """The map of the ``MAP_KEYS`` values ``settings``, built once for all the runs that play it (a
    contention's map may take a fifth of a second to draw)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a layout overriding generation keys: the trainer already said so
        return resolve_map(**dict(zip(MAP_KEYS, settings)))


def without_machine_paths(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` with each absolute cache directory (``CACHE_DIRS``) as its name: the study keeps its
    caches in its output directory (``OUT/pretrained``, ``OUT/curriculum_stages``; the pilot's in
    ``OUT/pilot``), so a record says which one without the path of the machine that made it.

    :param config: a run's composed config, as plain data (not changed).
    """
    plain = {**config}
    for section in CACHE_DIRS:
        where = plain.get(section, {}).get("cache_dir")
        if where is not None and Path(where).is_absolute():
            plain[section] = {**plain[section], "cache_dir": Path(where).name}
    return plain


def export_sweep(sweep_dir: Path, experiment: str) -> list[RunData]:
    """Every usable run below ``sweep_dir`` as :class:`RunData`, its config without machine paths
    (:func:`without_machine_paths`); unusable ones are skipped with a warning, and a step evaluated
    twice (a resumed run) keeps its later record."""
    runs = [
        run_data(run.dir, without_machine_paths(run.config), experiment, run.dir.relative_to(sweep_dir).as_posix())
        for run in load_runs(sweep_dir)
    ]
    return sorted(runs, key=lambda r: natural_key(Path(r.name)))


def latest_by_step(records: Sequence[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    """Evaluation records by their step; a step evaluated twice (a resumed run) keeps its later record.

    :param records: a run's evaluation records, in file order.
    """
    return {int(r["step"]): r for r in records if "step" in r}


def run_data(run_dir: Path, config: dict[str, Any], experiment: str, name: str) -> RunData:
    """One run directory's evaluations as :class:`RunData`; a step evaluated twice (a resumed run) keeps
    its later record."""
    records = read_metrics(run_dir, warn_incomplete=False)
    by_step = latest_by_step(records)
    steps = tuple(sorted(by_step))
    metrics = {
        m: tuple(_rounded(float(by_step[s][m])) for s in steps) for m in METRICS if all(m in by_step[s] for s in steps)
    }
    return RunData(experiment, name, config, steps, metrics, source_steps(records), map_optimum(config))


def write_data(path: Path, runs: list[RunData]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("".join(json.dumps(r.to_json(), separators=(",", ":"), sort_keys=True) + "\n" for r in runs))
    tmp.replace(path)


def read_data(path: Path) -> list[RunData]:
    """The runs of one experiment's data file."""
    runs = []
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise DataError(f"cannot read {path}: {err.strerror}") from None
    for number, line in enumerate(lines, start=1):
        try:
            r = json.loads(line)
            metrics = {k: tuple(v) for k, v in r["metrics"].items()}
            steps, before, optimum = tuple(r["steps"]), int(r["steps_before"]), r["optimal_return"]
            runs.append(RunData(r["experiment"], r["name"], r["config"], steps, metrics, before, optimum))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            raise DataError(f"{path}: line {number} is not a run record") from None
    return runs


def read_experiment(data_dir: Path, name: str) -> list[RunData]:
    """The runs of experiment ``name`` in ``data_dir``: ``<name>.jsonl``'s, none without the file."""
    path = data_dir / f"{name}.jsonl"
    return read_data(path) if path.exists() else []


def machine() -> str:
    """This machine, for the report: CPU model and cores, Python."""
    return f"{cpu_model()}, {cpus_available()} cores, Python {platform.python_version()}"


def git_output(*args: str) -> str:
    """``git ARGS`` in the package's checkout, its output stripped; "" outside a checkout or on an error."""
    try:
        run = subprocess.run(["git", *args], cwd=REPO_DIR, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return ""
    return run.stdout.strip()


def code_commit() -> str:
    """The commit the runs are made with, marked when the package or its configs (conf/) have uncommitted
    changes."""
    commit = git_output("rev-parse", "--short", "HEAD") or "unknown"
    dirty = bool(git_output("status", "--porcelain", "--", "dqn_transfer", "conf"))
    return commit + (" (with uncommitted changes)" if dirty else "")


def read_manifest(data_dir: Path) -> dict[str, Any]:
    path = data_dir / MANIFEST
    try:
        return json.loads(path.read_text())
    except OSError:
        return {}
    except json.JSONDecodeError:
        raise DataError(f"{path} is not valid JSON") from None


def data_digest(data_dir: Path) -> str:
    """The sha256 of a data directory's run records: each ``*.jsonl``'s name and bytes, by name (the manifest,
    which holds dates, commits and wall times, left out)."""
    digest = hashlib.sha256()
    for path in sorted(data_dir.glob("*.jsonl")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def write_manifest(data_dir: Path, manifest: dict[str, Any]) -> None:
    data_dir.mkdir(parents=True, exist_ok=True)
    (data_dir / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")


def experiment_records(manifest: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each experiment's record in a manifest (profile, commit, machine, date, wall_seconds, runs); the first
    edition's committed manifest holds one profile, commit, machine and date for all of them."""
    if "experiments" in manifest:
        return manifest["experiments"]
    shared: dict[str, Any] = {key: manifest[key] for key in ("profile", "commit", "machine", "date") if key in manifest}
    walls = manifest.get("wall_seconds", {})
    return {
        name: {**shared, "runs": runs, "wall_seconds": walls.get(name)}
        for name, runs in manifest.get("runs", {}).items()
    }


def is_smoke(records: dict[str, dict[str, Any]]) -> bool:
    """Whether data of these records are not evidence: none, or any not made with the full profile."""
    return not records or any(record.get("profile") != "full" for record in records.values())


@dataclass(frozen=True)
class Evidence:
    """What a report reads of a results directory before its analysis: where its data are, its manifest, each
    experiment's record (:func:`experiment_records`), and whether they are a smoke run's, not evidence."""

    data: Path
    manifest: dict[str, Any]
    records: dict[str, dict[str, Any]]
    smoke: bool

    @property
    def watermark(self) -> str | None:
        """What a figure of smoke data says across it."""
        return SMOKE_MARK if self.smoke else None


def write_json(path: Path, record: dict[str, Any]) -> None:
    """A stage's record (budgets, maps) as indented JSON, its directory made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1) + "\n")


def carry_file(results: Path, out: Path, relative: Path) -> bool:
    """Whether ``results`` has the file ``relative``; copied into ``out`` at the same relative path if that
    is elsewhere, so that a report written anywhere holds its figures (and is the same bytes)."""
    source, beside = results / relative, out / relative
    if not source.is_file():
        return False
    if not beside.is_file() or not os.path.samefile(source, beside):
        beside.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, beside)
    return True


def read_evidence(results: Path) -> Evidence:
    """The :class:`Evidence` of ``RESULTS/data/``."""
    data = Path(results) / DATA_DIR
    manifest = read_manifest(data)
    records = experiment_records(manifest)
    return Evidence(data, manifest, records, is_smoke(records))
