"""Replicas on every core: a batch's replicas split across worker processes.

One process steps all the replicas of a run in lockstep through one batched learner, on one core.
With ``replicas.workers`` (``auto``: the cores this process may use, divided among the sweep's jobs
that run at once) the replicas are split into contiguous *shares*, each trained by a forked process
of its own (a :class:`~dqn_transfer.training.trainer.Trainer` over :meth:`RunPlan.share
<dqn_transfer.training.plan.RunPlan.share>`) into the same run directory, which ends up as one
process would have left it. A replica's numbers depend on its own seed and map alone (its random
streams, its rows of the stacked networks), so the run is the same bit for bit with any number of
workers (``tests/test_workers.py``).

The process that splits the run shows one progress bar (the slowest share's step) and forwards SIGINT
and SIGTERM to the workers, each in a process group of its own so that a terminal's Ctrl-C reaches it
once: each stops at the end of its step in progress with a checkpoint, as a lone process does, and
the run resumes with ``resume=true`` as usual. Workers stop at different steps, so a resumed run
groups its replicas by the step of their checkpoints, each group in workers of its own. A worker that
fails stops the others (at a checkpoint) and its error is the run's: one line for a user error
(:data:`USER_ERRORS`), its traceback for anything else.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import sys
import traceback
from collections.abc import Sequence
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf
from tqdm import tqdm

from dqn_transfer.config import ConfigError
from dqn_transfer.storage.checkpoint import CheckpointError, read_meta
from dqn_transfer.storage.run_dir import RunDir, RunDirError
from dqn_transfer.training.plan import RunPlan
from dqn_transfer.training.stop import Interrupted
from dqn_transfer.training.trainer import Sources, Trainer, check_start, in_multirun, write_replicas_index
from dqn_transfer.transfer.mapping import TransferError

log = logging.getLogger("dqn_transfer.train")

# The errors of a run that cannot start or continue as asked: one line for the user, no traceback.
USER_ERRORS = (ConfigError, CheckpointError, TransferError, RunDirError)
POLL_SECONDS = 0.5  # how often the progress bar is brought up to date


class WorkerFailed(RuntimeError):
    """A worker process failed with something other than a user error; its traceback is the message."""


def available_cores() -> int:
    """The cores this process may run on (its affinity: a SLURM job's allocation, a ``taskset``)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def sweep_jobs_at_once() -> int:
    """How many jobs of this process's sweep run at the same time: the joblib launcher's ``n_jobs``
    (joblib's meaning: -1 all cores, -2 all but one, ...), 1 outside a sweep or with another launcher
    (the basic one runs jobs one by one; submitit gives each job an allocation of its own)."""
    if not in_multirun():
        return 1
    n_jobs = OmegaConf.select(OmegaConf.create(OmegaConf.to_container(HydraConfig.get())), "launcher.n_jobs")
    if not isinstance(n_jobs, int) or n_jobs == 0:
        return 1
    return n_jobs if n_jobs > 0 else max(1, available_cores() + 1 + n_jobs)


def trainer_for(plan: RunPlan, run_dir: Path, **trainer: Any) -> Trainer | ReplicaWorkers:
    """What trains ``plan`` into ``run_dir``: this process, or worker processes (``replicas.workers``, and a
    resumed batch whose replicas stopped at different steps). ``trainer``: the
    :class:`~dqn_transfer.training.trainer.Trainer`'s keywords (``sources``, ``tag``, ``final_dirs``)."""
    workers = worker_count(plan.config.replicas.workers, len(plan.replicas))
    resumed_batch = plan.config.resume and len(plan.replicas) > 1
    forks = "fork" in multiprocessing.get_all_start_methods()  # not on Windows: one process there
    split = shares(plan, run_dir, workers) if forks and (workers > 1 or resumed_batch) else [(0, len(plan.replicas))]
    return Trainer(plan, run_dir, **trainer) if len(split) == 1 else ReplicaWorkers(plan, run_dir, split, **trainer)


def train_on_cores(plan: RunPlan, run_dir: Path, **trainer: Any) -> None:
    """Run (or resume) the planned run into ``run_dir`` as :func:`~dqn_transfer.training.trainer.train`
    does (the same keywords), in this process or in worker processes (:func:`trainer_for`): a transfer
    source's pretraining and a curriculum's stages use the cores as the run does."""
    trainer_for(plan, run_dir, **trainer).run()


def worker_count(setting: str, replicas: int) -> int:
    """The worker processes for ``replicas`` replicas: ``replicas.workers`` (``auto`` or a count; the
    schema has checked it), never more than the replicas."""
    wanted = max(1, available_cores() // sweep_jobs_at_once()) if setting == "auto" else int(setting)
    return max(1, min(wanted, replicas))


def checkpoint_steps(plan: RunPlan, run_dir: Path) -> list[int]:
    """Each replica's step in its resume state (a resumed batch's; refused where a replica has none)."""
    check_start(plan, run_dir)
    return [int(read_meta(RunDir(path).training_state)["counters"]["step"]) for path in plan.replica_dirs(run_dir)]


def shares(plan: RunPlan, run_dir: Path, workers: int) -> list[tuple[int, int]]:
    """``(first, count)`` of each worker's replicas: ``workers`` contiguous shares as even as can be, and
    for a resumed run, within groups of replicas whose checkpoints are at one step."""
    steps = checkpoint_steps(plan, run_dir) if plan.config.resume else [0] * len(plan.replicas)
    groups: list[tuple[int, int]] = []  # (first, count) of consecutive replicas at one step
    for r, step in enumerate(steps):
        if groups and steps[r - 1] == step:
            groups[-1] = (groups[-1][0], groups[-1][1] + 1)
        else:
            groups.append((r, 1))
    split = []
    for first, count in groups:
        parts = max(1, min(count, round(workers * count / len(steps))))
        bounds = [first + count * i // parts for i in range(parts + 1)]
        split += [(start, stop - start) for start, stop in zip(bounds, bounds[1:])]
    return split


class ReplicaWorkers:
    """A batch's replicas trained by worker processes (see the module docstring); :meth:`prepare` and
    :meth:`run` as a :class:`~dqn_transfer.training.trainer.Trainer`'s.

    :param plan: the run's plan (all its replicas)
    :param run_dir: the run directory
    :param split: ``(first, count)`` of each worker's replicas (:func:`shares`)
    :param sources: the transfer sources, one per replica (as the trainer takes them)
    :param tag: what starts every line the run logs (the trainer's; each worker adds its replicas)
    :param final_dirs: where each replica's directory ends up (the trainer's)
    """

    def __init__(
        self,
        plan: RunPlan,
        run_dir: Path,
        split: Sequence[tuple[int, int]],
        *,
        sources: Sources | None = None,
        tag: str = "",
        final_dirs: Sequence[Path] | None = None,
    ):
        self.plan, self.run_dir, self.split, self.sources = plan, Path(run_dir), list(split), sources
        self.tag, self.final_dirs = tag, final_dirs

    def prepare(self) -> None:
        """What the process that splits the run checks before it starts any worker: its directories allow
        the start (each worker checks the rest of its own start)."""
        check_start(self.plan, self.run_dir)

    def run(self) -> None:
        """Train every share in its worker; raises the first worker's error, or
        :class:`~dqn_transfer.training.stop.Interrupted` when a signal stopped them."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_replicas_index(self.plan, RunDir(self.run_dir))
        context = multiprocessing.get_context("fork")  # the workers start from this process's plan, as it is
        steps = context.Array("q", len(self.split), lock=False)
        for i in range(len(self.split)):
            steps[i] = -1
        workers, results = [], []
        for i, (first, count) in enumerate(self.split):
            receive, send = context.Pipe(duplex=False)
            sources = None if self.sources is None else list(self.sources)[first : first + count]
            final_dirs = None if self.final_dirs is None else list(self.final_dirs)[first : first + count]
            trainer = dict(
                sources=sources,
                tag=f"{self.tag} [replicas {first}-{first + count - 1}]".lstrip(),
                final_dirs=final_dirs,
            )
            worker = context.Process(
                target=_train_share,
                args=(self.plan.share(first, count), self.run_dir, trainer, i, steps, send),
                name=f"replicas-{first}-{first + count - 1}",
            )
            worker.start()
            send.close()
            workers.append(worker)
            results.append(receive)
        log.info(
            "%s%d replicas in %d worker processes (replicas.workers=%s)",
            f"{self.tag} " if self.tag else "",
            len(self.plan.replicas),
            len(workers),
            self.plan.config.replicas.workers,
        )
        signals: list[int] = []

        def forward(signum: int, frame: object) -> None:
            signals.append(signum)
            for worker in workers:
                if worker.is_alive():
                    os.kill(worker.pid, signum)  # type: ignore[arg-type]

        previous = {signum: signal.signal(signum, forward) for signum in (signal.SIGINT, signal.SIGTERM)}
        try:
            outcomes = self._wait(workers, results, steps)
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
        self._raise_first_failure(outcomes, signals)

    def _wait(self, workers: list[Any], results: list[Connection], steps: Any) -> list[tuple[Any, ...]]:
        """Each worker's outcome, as it sent it (``("failed", text)`` for one that sent none), the progress
        bar kept up to date meanwhile; the first failure stops the others."""
        config = self.plan.config
        bar = tqdm(
            total=config.total_steps,
            disable=not config.progress or not sys.stderr.isatty(),
            unit="step",
            dynamic_ncols=True,
            file=sys.stderr,
        )
        outcomes: list[tuple[Any, ...] | None] = [None] * len(workers)
        stopped = False
        try:
            while any(outcome is None for outcome in outcomes):
                wait([worker.sentinel for worker in workers], timeout=POLL_SECONDS)
                for i, (worker, result) in enumerate(zip(workers, results)):
                    if outcomes[i] is None and not worker.is_alive():
                        outcomes[i] = result.recv() if result.poll() else ("failed", f"exit code {worker.exitcode}")
                        worker.join()
                if not stopped and any(o is not None and o[0] in ("failed", "user_error") for o in outcomes):
                    stopped = True  # the others stop at a checkpoint
                    for worker in workers:
                        if worker.is_alive():
                            os.kill(worker.pid, signal.SIGTERM)
                reported = [s for s in steps[:] if s >= 0]
                if len(reported) == len(workers):
                    bar.update(min(reported) - bar.n)
        finally:
            bar.close()
        return [outcome for outcome in outcomes if outcome is not None]

    def _raise_first_failure(self, outcomes: list[tuple[Any, ...]], signals: list[int]) -> None:
        """The run's end as the workers' outcomes make it: a user error, a failure, a stop at once, a
        stop at a checkpoint (the earliest step), else nothing."""
        for outcome in outcomes:
            if outcome[0] == "user_error":
                raise ConfigError(outcome[1])
        for outcome in outcomes:
            if outcome[0] == "failed":
                raise WorkerFailed(f"a worker process failed: {outcome[1]}")
        if any(outcome[0] == "stopped" for outcome in outcomes):
            raise KeyboardInterrupt  # a worker stopped at once, before its loop or at a second Ctrl-C
        stops = [outcome for outcome in outcomes if outcome[0] == "interrupted"]
        if stops:
            raise Interrupted(signals[0] if signals else stops[0][1], min(o[2] for o in stops), self.run_dir)


def _train_share(
    plan: RunPlan, run_dir: Path, trainer: dict[str, Any], index: int, steps: Any, send: Connection
) -> None:
    """A worker: train ``plan`` (a share) into ``run_dir`` (``trainer``: the trainer's other keywords); send
    how it ended to the process that started it."""
    os.setpgid(0, 0)  # signals come from the parent only (a terminal's Ctrl-C would arrive twice)

    def stop_at_once(signum: int, frame: object) -> None:  # until the trainer's loop takes the signals over
        raise KeyboardInterrupt

    def report(step: int) -> None:
        steps[index] = step

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, stop_at_once)  # not the parent's forwarding
    try:
        Trainer(plan, run_dir, **trainer, report_step=report).run()
        send.send(("done",))
    except Interrupted as stop:
        send.send(("interrupted", stop.signum, stop.step))
    except KeyboardInterrupt:
        send.send(("stopped",))
    except USER_ERRORS as err:
        send.send(("user_error", str(err)))
    except BaseException:
        send.send(("failed", traceback.format_exc()))
    finally:
        send.close()
