"""Reading run directories: their evaluations (``metrics.jsonl``) and their Hydra configs.

A run directory is laid out as :mod:`dqn_transfer.storage.run_dir` says. Evaluations are read from the file,
never from live objects, so runs from any machine or SLURM job can be analysed; a run that is still
writing, or was killed mid-write, is read up to its last complete line.

Readers are given directories by the shell (``outputs/runs/<date>/*/``), and some of those are not
usable runs: a stub left by a refused run (``train.log`` and ``.hydra/`` only), a run that has not
evaluated yet. :func:`find_run_dirs` and :func:`load_runs` skip each with a :class:`SkippedRun`
warning that names it and says why, and only an empty result is an error.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.storage.jsonl import json_lines
from dqn_transfer.storage.run_dir import CONFIG_FILE, HYDRA_DIR, LOG_FILE, METRICS_FILE, RunDir, natural_key


class EvaluationError(Exception):
    """A run directory or its metrics cannot be used; the message is one user-facing line."""


class IncompleteLastLine(UserWarning):
    """A ``metrics.jsonl`` whose last line was cut short (a run still writing, or killed mid-write)."""


class SkippedRun(UserWarning):
    """A directory given to a reader that is not a usable run; the message is ``skipped DIR: REASON``."""


def read_metrics(run_dir: str | os.PathLike, warn_incomplete: bool = True) -> list[dict[str, Any]]:
    """All evaluation records of a run, in file order.

    A last line without its newline that does not parse is a write cut short by a killed run: it
    is skipped, with a warning unless ``warn_incomplete`` is false. Any other bad line is an error.
    """
    path = RunDir(run_dir).metrics
    if not Path(run_dir).exists():
        raise EvaluationError(f"{run_dir}: no such run directory")
    if not Path(run_dir).is_dir():
        raise EvaluationError(f"{run_dir}: not a directory (expected a run directory)")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise EvaluationError(
            f"{path}: missing; {run_dir} has no evaluations (not a run directory, or the run has not evaluated yet)"
        ) from None
    lines = text.split("\n")

    def bad_line(number: int) -> None:
        if number == len(lines):  # no trailing newline: interrupted append
            if warn_incomplete:
                warnings.warn(f"{path}: skipping incomplete last line {number}", IncompleteLastLine, stacklevel=4)
            return
        raise EvaluationError(f"{path}: line {number} is not valid JSON") from None

    records = []
    for number, record in json_lines(lines, bad_line):
        if not isinstance(record, dict):
            raise EvaluationError(f"{path}: line {number} is not a JSON object")
        records.append(record)
    return records


def learning_curve(run_dir: str | os.PathLike, metric: str = "team_return", warn_incomplete: bool = True) -> Curve:
    """``(steps, values)`` of ``metric`` over a run's evaluations, sorted by step.

    A resumed run re-evaluates the steps after its last checkpoint; for a repeated step the later
    record wins, since it belongs to the run that continued. ``warn_incomplete``: as :func:`read_metrics`.
    """
    records = read_metrics(run_dir, warn_incomplete)
    by_step: dict[int, float] = {}
    for record in records:
        if isinstance(record.get(metric), (int, float)) and "step" in record:
            by_step[int(record["step"])] = float(record[metric])
    if not by_step:
        available = sorted(
            {key for record in records for key, value in record.items() if isinstance(value, (int, float))} - {"step"}
        )
        raise EvaluationError(
            f"{RunDir(run_dir).metrics}: no {metric!r} evaluations (available: {', '.join(available) or 'none'})"
        )
    steps = np.array(sorted(by_step), dtype=np.float64)
    return steps, np.array([by_step[int(s)] for s in steps], dtype=np.float64)


def _is_hidden_below(path: Path, root: Path) -> bool:
    """A directory below ``root`` whose name starts with a dot: not a run even if it holds one, e.g. a
    source still pretraining in the cache (``.<hash>.tmp-*``)."""
    return any(part.startswith(".") for part in path.relative_to(root).parts)


def _candidates(path: Path) -> list[Path]:
    """The run directories ``path`` stands for: its replicas if it is a run of replicas; itself if it
    holds ``metrics.jsonl`` or is a Hydra job directory (``.hydra/``); else every such directory below
    it, naturally sorted (a sweep directory; a run of replicas there stands for its replicas)."""
    run = RunDir(path)
    if run.replicas_index.exists():
        return run.replica_dirs()
    if run.has_metrics() or run.hydra_dir.is_dir():
        return [path]
    found = {p.parent for name in (METRICS_FILE, HYDRA_DIR) for p in path.rglob(name)}
    return sorted(
        (d for d in found if not _is_hidden_below(d, path) and not RunDir(d).replicas_index.exists()), key=natural_key
    )


def _last_error(log_path: Path) -> str | None:
    """The last ``error: ...`` line of a run's log: why a refused run never evaluated."""
    try:
        lines = log_path.read_text(errors="replace").splitlines()
    except OSError:
        return None
    errors = [line[line.index("error: ") :] for line in lines if "error: " in line]
    return errors[-1] if errors else None


def _unusable_reason(run_dir: Path, need_config: bool = False) -> str | None:
    """Why ``run_dir`` is not a usable run (None if it is): it has no evaluations, or (``need_config``)
    no readable config."""
    files = RunDir(run_dir)
    if not files.has_metrics():
        error = _last_error(files.log)
        return f"no {METRICS_FILE} ({f'{LOG_FILE}: {error}' if error else 'the run has not evaluated'})"
    try:
        records = read_metrics(run_dir, warn_incomplete=False)  # the reader warns when it reads the curve
    except EvaluationError as err:
        return str(err)
    if not records:
        return f"{METRICS_FILE} holds no evaluations yet"
    if need_config and load_config(run_dir) is None:
        return f"no readable {HYDRA_DIR}/{CONFIG_FILE} (cannot tell its condition)"
    return None


def scan_run_dirs(
    paths: Sequence[str | os.PathLike], need_config: bool = False
) -> tuple[list[Path], list[tuple[Path, str]]]:
    """``(usable runs, [(skipped directory, why)])`` at or below ``paths``: a run directory given is
    taken in the given order, a directory above runs (a sweep) contributes the runs below it."""
    runs: list[Path] = []
    skipped: list[tuple[Path, str]] = []
    for given in paths:
        path = Path(given)
        candidates = _candidates(path) if path.is_dir() else []
        if not path.exists():
            skipped.append((path, "no such directory"))
        elif not path.is_dir():
            skipped.append((path, "not a directory"))
        elif not candidates:
            skipped.append((path, f"no {METRICS_FILE} at or below it"))
        for candidate in candidates:
            reason = _unusable_reason(candidate, need_config)
            if reason is None:
                runs.append(candidate)
            else:
                skipped.append((candidate, reason))
    return list(dict.fromkeys(p.resolve() for p in runs)), skipped


def _warn_skipped(skipped: Sequence[tuple[Path, str]]) -> None:
    for path, reason in skipped:
        warnings.warn(SkippedRun(f"skipped {path}: {reason}"), stacklevel=3)


def find_run_dirs(paths: Sequence[str | os.PathLike], kind: str = "run") -> list[Path]:
    """The usable run directories at or below ``paths`` (see :func:`scan_run_dirs`); each directory
    skipped is a :class:`SkippedRun` warning. Only finding none is an error, whose message is the one
    reason when a single directory was skipped."""
    runs, skipped = scan_run_dirs(paths)
    if not runs and len(skipped) == 1:
        path, reason = skipped[0]
        raise EvaluationError(f"{path}: {reason}")
    _warn_skipped(skipped)
    if not paths:
        raise EvaluationError(f"no {kind} directory given")
    if not runs:
        raise EvaluationError(f"no usable {kind} directory among the {len(paths)} given ({len(skipped)} skipped)")
    return runs


@contextlib.contextmanager
def skipped_runs_on_stderr() -> Iterator[None]:
    """For the command lines: every :class:`SkippedRun` as its own ``skipped DIR: REASON`` line on stderr,
    any other user warning as one ``warning: ...`` line; incomplete last lines of runs still writing are
    expected and not shown."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(("" if issubclass(category, SkippedRun) else "warning: ") + str(message), file=sys.stderr)

    with warnings.catch_warnings():
        warnings.simplefilter("always", UserWarning)  # every skipped directory, not the first of each kind
        warnings.simplefilter("ignore", IncompleteLastLine)
        warnings.showwarning = show
        yield


def steps_before(run_dir: str | os.PathLike) -> int:
    """The env steps spent before a run's own step 0 on what it warm-started from: its source's steps,
    and those of the source's own source, down the chain a curriculum records (0 without transfer).
    Read from the first evaluation's ``transfer_source`` record."""
    return source_steps(read_metrics(run_dir))


def source_steps(records: Sequence[dict[str, Any]]) -> int:
    """:func:`steps_before` from a run's evaluation records already read."""
    record = records[0].get("transfer_source") if records else None
    total = 0
    while isinstance(record, dict):
        total += int(record.get("source_steps") or 0)
        record = record.get("source_transfer")
    return total


def load_config(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The run's composed Hydra config (``.hydra/config.yaml``), or None if unreadable."""
    try:
        config = yaml.safe_load(RunDir(run_dir).config.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return config if isinstance(config, dict) else None


def run_seed(run_dir: str | os.PathLike) -> int | None:
    """The run's ``seed`` from its Hydra config, if readable."""
    seed = (load_config(run_dir) or {}).get("seed")
    return seed if isinstance(seed, int) else None


@dataclass
class Run:
    """A run directory with its config, for analyses that tell conditions apart by config values."""

    dir: Path
    config: dict[str, Any]


def load_runs(directory: Path) -> list[Run]:
    """Every usable run below ``directory`` with its config; [] if there is none (or no such directory).

    A directory below it that is not a usable run, or has no readable config (its condition cannot be
    told), is skipped with a :class:`SkippedRun` warning.
    """
    if not directory.is_dir():
        return []
    run_dirs, skipped = scan_run_dirs([directory], need_config=True)
    _warn_skipped(skipped)
    return [Run(run_dir, load_config(run_dir)) for run_dir in run_dirs]  # type: ignore[arg-type]


def run_objective(run_dir: str | os.PathLike, objective: str, metric: str = "team_return") -> float:
    """What a run returns to a Hydra sweeper (``objective`` in the config): ``metric``'s last evaluation
    (``final``) or its mean over all evaluations (``mean``), read from ``metrics.jsonl``; for a run of
    replicas, the mean of its replicas' values."""
    if objective not in ("final", "mean"):
        raise ValueError(f"objective is final or mean, got {objective!r}")
    dirs = RunDir(run_dir).replica_dirs() or [Path(run_dir)]
    values = [learning_curve(d, metric, warn_incomplete=False)[1] for d in dirs]
    return float(np.mean([v[-1] if objective == "final" else v.mean() for v in values]))
