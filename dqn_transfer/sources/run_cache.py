"""A directory of finished runs, one per key, that parallel jobs fill once and never see half-made.

The pretrained transfer sources (:mod:`dqn_transfer.sources.resolve`) and the curriculum's stages
(:mod:`dqn_transfer.sources.curriculum`) are both such caches: ``<root>/<key>/`` is an ordinary run directory
that appears whole or not at all.

- A run is trained in a hidden sibling and renamed to ``<key>/`` once complete. Several missing
  entries of one batch of replicas are trained together, as one run of replicas, and each replica's
  directory becomes its own entry.
- ``<root>/.<key>.lock`` (``flock``, outside the entry, never deleted: unlinking a lock file lets a job
  that opened it before lock a file nobody else will see) makes parallel jobs train an entry once; a
  batch takes its locks in key order, so two jobs never wait for each other in a circle.
- The hidden sibling is ``.<key>.tmp-<pid>-<random>/``, removed on any failure, or, for a *resumable*
  cache, ``.<key>.partial/``: kept when the run is interrupted or killed, and resumed from its last
  checkpoint by the next job that needs the entry.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import secrets
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from dqn_transfer.storage.checkpoint import load_agent_checkpoint
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.stop import Interrupted
from dqn_transfer.transfer.mapping import TransferError

log = logging.getLogger("dqn_transfer.transfer")
T = TypeVar("T")


class RunCache:
    """Finished runs under ``root``, one per key.

    :param root: the cache directory (created when first needed)
    :param name: what the cache is, for messages ("the pretraining cache")
    :param setting: the config key that moves it, for messages ("transfer.cache_dir")
    :param resumable: keep an interrupted run's directory and resume it, instead of starting afresh
    """

    def __init__(self, root: Path, name: str, setting: str, *, resumable: bool = False) -> None:
        self.root, self.name, self.setting, self.resumable = root, name, setting, resumable

    def entry(self, key: str) -> RunDir:
        return RunDir(self.root / key)

    @staticmethod
    def finished(entry: RunDir, steps: int) -> bool:
        """Whether ``entry`` holds a run that reached ``steps`` (as its agent 0 checkpoint says)."""
        checkpoint = entry.agent_checkpoint(0)
        return checkpoint.exists() and load_agent_checkpoint(checkpoint)[1].get("steps") == steps

    def fill(
        self, keys: list[str], complete: Callable[[RunDir], bool], train_into: Callable[[list[int], Path, bool], None]
    ) -> list[int]:
        """Make the entry of every key complete; returns the indices of those trained now.

        ``complete(entry)`` says whether an entry is finished (checked before and, under the locks,
        again: another job may have filled it meanwhile). ``train_into(indices, work_dir, resume)``
        trains the entries ``indices`` into ``work_dir`` (as a run of replicas when there are several:
        all of ``keys`` missing), resuming the run there if ``resume``.
        """
        entries = [self.entry(key) for key in keys]
        done = [complete(entry) for entry in entries]  # complete once it exists: no lock
        if all(done):
            return []
        with contextlib.ExitStack() as locks:
            for key in sorted(set(keys)):
                locks.enter_context(self._lock(key))
            missing = [i for i, entry in enumerate(entries) if not (done[i] or complete(entry))]
            groups = [missing] if len(missing) == len(keys) > 1 else [[i] for i in missing]
            work_dirs = [self._work_dir(keys[group[0]], len(group)) for group in groups]
            # Under the locks nobody else trains these keys: what is there was left by a killed run,
            # except the work directories about to be resumed.
            for i in missing:
                for leftover in [
                    *self.root.glob(f".{keys[i]}.tmp-*"),
                    *self.root.glob(f".{keys[i]}.partial*"),
                    entries[i].path,
                ]:
                    if leftover not in work_dirs:
                        self.remove(leftover, keys[i])
            for group, work in zip(groups, work_dirs):
                self._train(group, work, [entries[i] for i in group], keys[group[0]], train_into)
        return missing

    def _work_dir(self, key: str, replicas: int) -> Path:
        if not self.resumable:
            return self.root / f".{key}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
        return self.root / (f".{key}.partial" if replicas == 1 else f".{key}.partial-{replicas}-replicas")

    def _train(
        self,
        group: list[int],
        work: Path,
        entries: list[RunDir],
        key: str,
        train_into: Callable[[list[int], Path, bool], None],
    ) -> None:
        """Train ``group`` into ``work`` (resuming it if it holds a checkpoint), then move each run to its entry."""
        resume = self.resumable and RunDir(work).has_run()
        if not resume:
            self.remove(work, key)  # a resumable run killed before its first checkpoint: start afresh
        try:
            train_into(group, work, resume)
            runs = RunDir(work).replica_dirs() or [work]
            for run, entry in zip(runs, entries):
                self.call(os.rename, run, entry.path, where=entry)
            self.remove(work, key)
        except (Interrupted, KeyboardInterrupt):  # Ctrl-C, SIGTERM: a resumable run continues next time
            if not self.resumable:
                self.remove(work, key)
            raise
        except BaseException:  # an error: leave nothing half-made
            self.remove(work, key)
            raise

    @contextlib.contextmanager
    def _lock(self, key: str) -> Iterator[None]:
        """Hold ``<root>/.<key>.lock`` exclusively (the file is kept, see the module docstring)."""
        self.call(self.root.mkdir, parents=True, exist_ok=True, where=self.root)
        with self.call(open, self.root / f".{key}.lock", "a", where=self.root) as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                log.info("waiting for another job writing %s", self.entry(key))
                fcntl.flock(lock, fcntl.LOCK_EX)
            yield  # closing the file releases the lock

    def call(self, fn: Callable[..., T], *args: Any, where: Path | RunDir, **kwargs: Any) -> T:
        """``fn(*args, **kwargs)``, with an OSError turned into the cache's one-line TransferError."""
        try:
            return fn(*args, **kwargs)
        except OSError as err:
            raise TransferError(
                f"cannot use {self.name} {where}: {err.strerror} (set {self.setting} to a writable directory)"
            ) from None

    @staticmethod
    def remove(path: Path, key: str) -> None:
        """Delete a leftover directory tree of the entry ``key``, quietly (it runs while an error or an
        interrupt is on its way up). It is first renamed out of the way: an interrupted run's
        TensorBoard writer appends to its event file by name and could recreate it while rmtree runs;
        and the new name is a temp name, so a removal cut short is cleaned by the next run of ``key``."""
        if not path.exists():
            return
        doomed = path.with_name(f".{key}.tmp-removing-{secrets.token_hex(4)}")
        try:
            path.rename(doomed)
        except OSError:
            doomed = path
        shutil.rmtree(doomed, ignore_errors=True)
