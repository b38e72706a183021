"""The layout of a run directory, owned here: every writer and reader goes through :class:`RunDir`.

::

    RUN/
      .hydra/config.yaml      the composed config (Hydra writes it; resume rewrites it with the run's own)
      .hydra/overrides.yaml   the command line's overrides
      metrics.jsonl           one greedy evaluation per line
      train.log               the run's log
      tb/                     TensorBoard event files
      scalars.csv             the same scalars as rows step,tag,value (logger=[...,csv])
      wandb/                  Weights & Biases' local run directory (logger=[...,wandb])
      checkpoints/agent_{i}.safetensors     one file per agent, shareable on its own
      checkpoints/training_state.safetensors  what resume needs besides the agents

A run of replicas (``replicas.seeds`` x ``replicas.maps``) holds, besides ``.hydra/`` and its log,
``replicas.json`` (the names of its replicas) and one such run directory per replica.

The module imports nothing of the package, so the checkpoint files, the trainer and the analysis
can all use it. :class:`RunClaim` is how a run takes a directory for itself (and gives it back).
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HYDRA_DIR = ".hydra"
CONFIG_FILE = "config.yaml"
OVERRIDES_FILE = "overrides.yaml"
METRICS_FILE = "metrics.jsonl"
LOG_FILE = "train.log"
TENSORBOARD_DIR = "tb"
SCALARS_CSV_FILE = "scalars.csv"
WANDB_DIR = "wandb"
WANDB_ID_FILE = "wandb_id"  # inside WANDB_DIR: the ids of the run's W&B runs (one per resume), one a line
CHECKPOINTS_DIR = "checkpoints"
TRAINING_STATE_FILE = "training_state.safetensors"
AGENT_FILE_GLOB = "agent_*.safetensors"
REPLICAS_FILE = "replicas.json"


def agent_file_name(index: int) -> str:
    return f"agent_{index}.safetensors"


def natural_key(path: str | os.PathLike) -> list[Any]:
    """Sort ``agent_2`` before ``agent_10`` and Hydra job ``2`` before ``10``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", str(path))]


def hashable(value: Any) -> Any:
    """A config value as a dictionary key or set member: a list becomes a tuple."""
    return tuple(value) if isinstance(value, list) else value


def flatten(tree: Mapping[str, Any], leaf: Callable[[Any], Any] = hashable, prefix: str = "") -> dict[str, Any]:
    """A run's config by dotted keys: ``{"env": {"mode": "x"}}`` -> ``{"env.mode": leaf("x")}``.

    :param tree: the composed config, as plain data.
    :param leaf: what each value that is not a mapping becomes (by default lists become tuples).
    :param prefix: put before every key.
    """
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, leaf, f"{name}."))
        else:
            flat[name] = leaf(value)
    return flat


@dataclass(frozen=True)
class RunDir:
    """One run directory (it need not exist yet)."""

    path: Path

    def __init__(self, path: str | os.PathLike) -> None:
        object.__setattr__(self, "path", Path(path))

    def __str__(self) -> str:
        return str(self.path)

    @property
    def hydra_dir(self) -> Path:
        return self.path / HYDRA_DIR

    @property
    def config(self) -> Path:
        return self.hydra_dir / CONFIG_FILE

    @property
    def overrides(self) -> Path:
        return self.hydra_dir / OVERRIDES_FILE

    @property
    def metrics(self) -> Path:
        return self.path / METRICS_FILE

    @property
    def log(self) -> Path:
        return self.path / LOG_FILE

    @property
    def tensorboard(self) -> Path:
        return self.path / TENSORBOARD_DIR

    @property
    def scalars_csv(self) -> Path:
        return self.path / SCALARS_CSV_FILE

    @property
    def wandb(self) -> Path:
        return self.path / WANDB_DIR

    @property
    def wandb_id(self) -> Path:
        return self.wandb / WANDB_ID_FILE

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS_DIR

    @property
    def training_state(self) -> Path:
        return self.checkpoints / TRAINING_STATE_FILE

    def agent_checkpoint(self, index: int) -> Path:
        return self.checkpoints / agent_file_name(index)

    @property
    def replicas_index(self) -> Path:
        return self.path / REPLICAS_FILE

    def replica_dirs(self) -> list[Path]:
        """The replicas' run directories, if this is a run of replicas (else none)."""
        try:
            names = [str(name) for name in json.loads(self.replicas_index.read_text())["replicas"]]
        except (OSError, ValueError, KeyError, TypeError):
            return []
        # Plain names only: the index may come from elsewhere, and what it names may be cleared.
        return [self.path / name for name in names if name not in ("", ".", "..") and Path(name).name == name]

    def has_run(self) -> bool:
        """Whether a run has checkpointed here (what resume continues and a new run must not overwrite)."""
        return self.training_state.exists() or any(RunDir(d).has_run() for d in self.replica_dirs())

    def has_metrics(self) -> bool:
        return self.metrics.is_file()

    def run_files(self) -> list[str]:
        """The names of the run's own files and folders that exist (its log and config included)."""
        return [
            p.name
            for p in (
                self.hydra_dir,
                self.metrics,
                self.tensorboard,
                self.scalars_csv,
                self.wandb,
                self.checkpoints,
                self.log,
                self.replicas_index,
            )
            if p.exists()
        ]

    def holds_run(self) -> bool:
        """Whether anything of a run is here: a new run must not mix its files with it."""
        return bool(self.run_files())


class RunDirError(Exception):
    """A run directory cannot be used for this run; the message is one user-facing line."""


class RunClaim:
    """This process's exclusive hold on a run directory, and what it added there.

    ``acquire`` locks the directory itself (``flock`` on its descriptor: no lock file to leave
    behind), so a second process pointed at a directory in use is refused; a new run is refused in a
    directory that already holds a run. ``undo`` removes what this process added, so a refused run
    leaves the file system as it found it.
    """

    def __init__(self, run: RunDir) -> None:
        self.run = run
        self._fd: int | None = None
        self._created: Path | None = None  # the first directory of the path this process created
        self._entries_before: set[str] = set()
        self._records_before: dict[Path, bytes] = {}  # a resumed run's config record and log, as they were

    def acquire(self, *, resume: bool, fresh: bool = False) -> None:
        """Lock the directory, creating it if needed; ``fresh``: it was just created for this run
        (a multirun job's directory), so ``undo`` removes it whole."""
        path = self.run.path.absolute()
        if (file := file_in_the_way(path)) is not None:
            raise RunDirError(f"cannot use {path} as a run directory: {file} is a file (choose another hydra.run.dir)")
        missing = [p for p in (path, *path.parents) if not p.exists()]
        self._created = path if fresh else (missing[-1] if missing else None)
        self._entries_before = set() if fresh or not path.exists() else set(os.listdir(path))
        try:
            path.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(path, os.O_RDONLY)
        except OSError as err:
            raise RunDirError(f"cannot create the run directory {path}: {err.strerror}") from None
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.release()
            raise RunDirError(
                f"{path} is in use by another running process; wait for it or choose another hydra.run.dir"
            ) from None
        if not fresh and not resume and self.run.holds_run():
            self.release()
            raise RunDirError(existing_run_message(self.run))
        if resume:  # Hydra is about to rewrite .hydra/ and append to the log: undo puts them back
            records = [*self.run.hydra_dir.glob("*"), self.run.log] if self.run.hydra_dir.is_dir() else [self.run.log]
            self._records_before = {p: p.read_bytes() for p in records if p.is_file()}

    def recorded_config(self) -> bytes | None:
        """A resumed run's config record (``.hydra/config.yaml``) as it was before this process claimed the
        directory (Hydra rewrites it then); None without one."""
        return self._records_before.get(self.run.config)

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the lock
            self._fd = None

    def undo(self) -> None:
        """Release, and remove what this process added: the directory if it created it, else the
        entries that were not there before."""
        self.release()
        if self._created is not None:
            shutil.rmtree(self._created, ignore_errors=True)
            return
        path = self.run.path
        for name in set(os.listdir(path)) - self._entries_before if path.is_dir() else ():
            entry = path / name
            shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)
        for record, content in self._records_before.items():
            record.parent.mkdir(parents=True, exist_ok=True)
            record.write_bytes(content)
        hydra_files = self.run.hydra_dir.glob("*") if self.run.hydra_dir.is_dir() else ()
        for added in [p for p in hydra_files if self._records_before and p not in self._records_before]:
            added.unlink(missing_ok=True)


def file_in_the_way(path: Path) -> Path | None:
    """``path`` itself or the nearest of its parents that exists and is not a directory (so no directory can be
    made at ``path``); None if there is none.

    :param path: where a directory is to be.
    """
    path = path.absolute()
    return next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)


def existing_run_message(run: RunDir) -> str:
    """Why a new run may not start in ``run``, and what to do instead."""
    if run.has_run():
        return (
            f"{run} already holds a run; pass resume=true to continue it, or choose another hydra.run.dir for a new one"
        )
    return (
        f"{run} already holds files of a run ({', '.join(sorted(run.run_files()))}) but no checkpoint "
        "to resume from; choose another hydra.run.dir (or delete it)"
    )
