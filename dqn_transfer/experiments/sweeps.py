"""Running Hydra multiruns of the study's experiments (:class:`Multirun`), each into its own directory.

A sweep directory already complete for the same settings is reused (so a failed report or a second
``--only`` does not rerun it); one holding other or unfinished runs is an error, never overwritten.
"""

from __future__ import annotations

import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser

from dqn_transfer.analysis.runs import EvaluationError, load_config, read_metrics
from dqn_transfer.config import CONFIG_DIR, register_configs
from dqn_transfer.storage.run_dir import RunDir

RUNS_DIR = "runs"  # OUT/runs/<experiment>/: the sweeps' run directories (checkpoints, logs; not committed)
STAMP_FILE = "reproduce.json"  # in OUT/<name>/: the settings the sweep ran with, and its wall time
DEFAULT_LAUNCHER = "joblib"
# The pyproject extra that installs each launcher plugin (basic is Hydra's own).
LAUNCHER_EXTRAS = {"joblib": "sweep", "submitit_slurm": "slurm", "submitit_local": "slurm"}


class ReproduceError(Exception):
    """A failed sweep or unusable results; the message is for the user, the CLI exits 1."""


def quoted_path(value: str | Path) -> str:
    """A path as a Hydra override value (quoted: spaces, '=' and ',' are grammar)."""
    text = str(value)
    if "'" in text:
        raise ReproduceError(f"{text}: paths with a single quote cannot be passed to Hydra; choose another --out")
    return f"'{text}'"


def composed(experiment: str, overrides: Sequence[str] = (), hydra_config: bool = False) -> Any:
    """``experiment=<experiment>``'s config with ``overrides`` (with Hydra's own settings if ``hydra_config``)."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(
            config_name="config", overrides=[f"experiment={experiment}", *overrides], return_hydra_config=hydra_config
        )


def swept_values(experiment: str, overrides: Sequence[str] = ()) -> dict[str, list[str]]:
    """Each key of the experiment file's sweep, with ``overrides`` applied (the command line replaces a file's
    key), and its values in sweep order."""
    params = {
        key: str(value) for key, value in (composed(experiment, hydra_config=True).hydra.sweeper.params or {}).items()
    }
    parser = OverridesParser.create()
    for text, override in zip(overrides, parser.parse_overrides(list(overrides))):
        params[override.get_key_element()] = text.split("=", 1)[1]
    return {
        override.get_key_element(): (
            list(override.sweep_string_iterator())
            if override.is_sweep_override()
            else [override.get_value_element_as_str()]
        )
        for override in parser.parse_overrides([f"{k}={v}" for k, v in params.items()])
    }


def count_jobs(name: str, overrides: Sequence[str]) -> int:
    """How many jobs the multirun launches: the experiment file's sweep with ``overrides`` applied."""
    return math.prod(len(values) for values in swept_values(name, overrides).values())


def installed_launchers() -> list[str]:
    """The Hydra launchers this Python has: ``basic`` always, the others if their plugin imports."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return GlobalHydra.instance().config_loader().get_group_options("hydra/launcher")


def chosen_experiments(only: str, known: Sequence[str], n_jobs: int) -> list[str]:
    """The experiments of ``--only`` (comma-separated, each one of ``known``), after checking ``--n-jobs``,
    so that bad input is refused before anything runs."""
    names = [name.strip() for name in only.split(",") if name.strip()]
    unknown = [name for name in names if name not in known]
    if unknown:
        raise ReproduceError(f"--only: unknown experiment(s) {', '.join(unknown)} (choose from {', '.join(known)})")
    if n_jobs < 1:
        raise ReproduceError(f"--n-jobs must be >= 1, got {n_jobs}")
    return names


def choose_launcher(requested: str | None) -> str:
    """The launcher the sweeps run with: ``requested``, refused if it is not installed; by default
    joblib, or Hydra's basic launcher (one job at a time) with one line saying so when joblib's plugin
    is missing, which is the case with only the ``dev`` extra installed."""
    installed = installed_launchers()
    if requested is None:
        if DEFAULT_LAUNCHER in installed:
            return DEFAULT_LAUNCHER
        print(
            f"the {DEFAULT_LAUNCHER} launcher is not installed: running one job at a time with Hydra's basic "
            f"launcher (for --n-jobs at a time: {_pip_install(DEFAULT_LAUNCHER)})",
            flush=True,
        )
        return "basic"
    if requested in installed:
        return requested
    if requested in LAUNCHER_EXTRAS:
        raise ReproduceError(f"--launcher {requested}: its Hydra plugin is not installed ({_pip_install(requested)})")
    raise ReproduceError(f"--launcher {requested}: no such Hydra launcher (installed: {', '.join(installed)})")


def _pip_install(launcher: str) -> str:
    return f'pip install -e ".[{LAUNCHER_EXTRAS[launcher]}]"'


def launcher_overrides(launcher: str, n_jobs: int) -> list[str]:
    if launcher == "basic":
        return []
    if launcher == "joblib":
        return ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={n_jobs}"]
    return [f"hydra/launcher={launcher}"]  # e.g. submitit_slurm / submitit_local, with --extra settings


def run_is_complete(run_dir: Path) -> bool:
    """The run (every replica of a run of replicas) evaluated at its last step."""
    replicas = RunDir(run_dir).replica_dirs()
    if replicas:
        return all(run_is_complete(replica) for replica in replicas)
    config = load_config(run_dir)
    if config is None or not RunDir(run_dir).has_metrics():
        return False
    try:
        records = read_metrics(run_dir, warn_incomplete=False)
    except EvaluationError:
        return False
    return bool(records) and max(int(r.get("step", -1)) for r in records) >= int(config.get("total_steps", 0))


def job_dirs(sweep_dir: Path) -> list[Path]:
    """Hydra's numbered job directories of a multirun."""
    if not sweep_dir.is_dir():
        return []
    return sorted((p for p in sweep_dir.iterdir() if p.is_dir() and p.name.isdigit()), key=lambda p: int(p.name))


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").rstrip().splitlines()
    except OSError:
        return f"    ({path} is unreadable)"
    return "\n".join("    " + line for line in text[-lines:]) or "    (empty)"


def failure_message(name: str, sweep_dir: Path, log_path: Path, expected: int, returncode: int) -> str:
    """Which runs failed, with the tail of each one's log, or of the sweep log if no run explains it."""
    runs = job_dirs(sweep_dir)
    bad = [d for d in runs if not run_is_complete(d)]
    parts = [
        f"experiment {name} failed (exit code {returncode}): {len(runs) - len(bad)}/{expected} runs "
        f"complete in {sweep_dir}"
    ]
    for run in bad[:5]:
        files = RunDir(run)
        what = " ".join(yaml.safe_load(files.overrides.read_text()) or []) if files.overrides.exists() else "?"
        parts.append(f"  run {run} ({what}) is incomplete; tail of {files.log}:\n{_tail(files.log)}")
    if len(bad) > 5:
        parts.append(f"  ... and {len(bad) - 5} more incomplete runs")
    if len(runs) < expected:
        parts.append(f"  {expected - len(runs)} jobs never started")
    parts.append(f"  tail of the sweep log {log_path}:\n{_tail(log_path, 25)}")
    return "\n".join(parts)


def read_stamp(sweep_dir: Path) -> dict | None:
    """The settings and wall time a finished sweep recorded (``STAMP_FILE``), None if it has none."""
    try:
        return json.loads((sweep_dir / STAMP_FILE).read_text())
    except (OSError, ValueError):
        return None


def write_stamp(sweep_dir: Path, stamp: dict) -> None:
    """Record a sweep's settings and the wall time of its attempts (``STAMP_FILE``), read by :func:`read_stamp`."""
    (sweep_dir / STAMP_FILE).write_text(json.dumps(stamp, indent=2) + "\n")


@dataclass(frozen=True)
class Multirun:
    """One Hydra multirun of an experiment config (``python -m dqn_transfer.cli.train -m experiment=...``)."""

    label: str  # names it in the progress lines and its log, OUT/logs/<label>.log
    experiment: str  # the option of conf/experiment/
    overrides: tuple[str, ...]
    sweep_dir: Path
    jobs: int  # the job directories a finished multirun holds
    stamp: dict  # the settings it runs with: a directory finished with the same ones is reused
    keep_checkpoints: bool = True  # False: delete its runs' checkpoints once it has finished (its metrics stay)


def run_multirun(
    multirun: Multirun,
    out: Path,
    launcher: str,
    n_jobs: int,
    extra: Sequence[str] = (),
    poll_seconds: float = 2.0,
) -> float:
    """Run ``multirun`` in a subprocess (its log in ``OUT/logs/``), a progress line per change; returns its
    wall time (all its attempts'), 0 when its directory already holds it, finished with the same settings.
    A sweep stopped unfinished (Ctrl-C, a crash) with the same settings continues where it stopped: each
    job from its last checkpoint, the complete ones as they are (``resume=true`` on the multirun)."""
    name, expected, stamp = multirun.label, multirun.jobs, dict(multirun.stamp)
    # No more joblib processes than jobs: a run's replicas.workers=auto share the cores among them.
    n_jobs = max(1, min(n_jobs, expected))
    # Absolute: the subprocess runs in OUT, where a relative sweep directory would land one level deeper.
    out, sweep_dir = out.resolve(), multirun.sweep_dir.resolve()
    earlier: list[float] = []  # the wall seconds of the attempts before this one
    if sweep_dir.exists() and any(sweep_dir.iterdir()):
        previous = read_stamp(sweep_dir)
        if previous is None or {k: previous.get(k) for k in stamp} != stamp:
            what = "runs of other settings" if previous is not None else f"runs without their {STAMP_FILE}"
            raise ReproduceError(
                f"{sweep_dir} already holds {what}; delete it or choose another --out "
                "(--report-only analyses what is there)"
            )
        earlier = list(previous.get("attempt_seconds", []))
        complete = sum(run_is_complete(d) for d in job_dirs(sweep_dir))
        if "wall_seconds" in previous and complete == len(job_dirs(sweep_dir)) == expected:  # finished
            print(f"[{name}] reusing the {expected} complete runs in {sweep_dir}", flush=True)
            if not multirun.keep_checkpoints:
                drop_checkpoints(sweep_dir)
            return 0.0
        print(f"[{name}] continuing where it stopped: {complete}/{expected} runs complete", flush=True)
        extra = [*extra, "resume=true"]
    # The settings first: a sweep stopped unfinished is known by them, and continued.
    sweep_dir.mkdir(parents=True, exist_ok=True)
    write_stamp(sweep_dir, {**stamp, "attempt_seconds": earlier})
    command = [
        sys.executable,
        "-m",
        "dqn_transfer.cli.train",
        "-m",
        f"experiment={multirun.experiment}",
        *multirun.overrides,
        f"hydra.sweep.dir={quoted_path(sweep_dir)}",
        "progress=false",
        *launcher_overrides(launcher, n_jobs),
        *extra,
    ]
    log_path = out / "logs" / f"{name}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env.setdefault(var, "1")  # parallel jobs of small MLPs: more torch threads only contend
    how = f"{launcher}" + (f", {n_jobs} at a time" if launcher == "joblib" else "")
    print(f"[{name}] {expected} jobs ({how}) -> {sweep_dir}\n[{name}] log: {log_path}", flush=True)
    start = time.perf_counter()
    with log_path.open("a" if earlier else "w") as log:  # a continued sweep's log goes on
        log.write("$ " + shlex.join(command) + "\n\n")
        log.flush()
        process = subprocess.Popen(command, cwd=out, stdout=log, stderr=subprocess.STDOUT, env=env)
        done, printed = -1, -math.inf
        finished: set[Path] = set()  # a finished job stays finished: its configs and metrics are read once
        try:
            while process.poll() is None:
                time.sleep(poll_seconds)
                finished |= {d for d in job_dirs(sweep_dir) if d not in finished and run_is_complete(d)}
                now = len(finished)
                elapsed = time.perf_counter() - start
                if now != done and (elapsed - printed >= 10 or now == expected):  # a line per change, at most 10 s
                    done, printed = now, elapsed
                    print(f"[{name}] {done}/{expected} runs done ({elapsed:.0f} s)", flush=True)
        except KeyboardInterrupt:  # the sweep had the same Ctrl-C: its jobs stop at a checkpoint, waited for
            process.wait()
            raise
        finally:
            attempts = [*earlier, round(time.perf_counter() - start, 1)]
            write_stamp(sweep_dir, {**stamp, "attempt_seconds": attempts})
    runs = job_dirs(sweep_dir)
    if process.returncode != 0 or len(runs) != expected or not all(run_is_complete(d) for d in runs):
        raise ReproduceError(failure_message(name, sweep_dir, log_path, expected, process.returncode))
    elapsed = sum(attempts)
    write_stamp(sweep_dir, {**stamp, "attempt_seconds": attempts, "wall_seconds": elapsed})
    if not multirun.keep_checkpoints:
        drop_checkpoints(sweep_dir)
    print(f"[{name}] {expected}/{expected} runs done in {elapsed:.0f} s", flush=True)
    return elapsed


def drop_checkpoints(sweep_dir: Path) -> None:
    """Delete the checkpoints of a multirun's runs (a run of replicas: each replica's); their metrics, config
    and logs stay. A finished Double DQN run's last checkpoint holds its replay buffers: gigabytes a run."""
    for job in job_dirs(sweep_dir):
        for run in (job, *RunDir(job).replica_dirs()):
            shutil.rmtree(RunDir(run).checkpoints, ignore_errors=True)
