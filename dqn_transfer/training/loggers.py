"""Where a run's scalars, evaluation pictures and config go: the backends ``logger`` names.

:class:`RunLoggers` is what a replica logs to: it drops the points without a value (NaN, None: no
update yet) once and hands the rest to each backend of the run's ``logger`` list. The points of the
training episodes' ends, the most frequent by far, wait in arrays (:class:`PendingRows`) and go to
the backends in one batch at the next :meth:`RunLoggers.flush` (the loop's log interval, its
checkpoints, its end) or before any other point, so every backend gets the points in step order:

* ``tensorboard`` (the default): :class:`~dqn_transfer.training.tensorboard.RunLogger`, ``tb/``;
* ``csv``: :class:`CsvLogger`, ``scalars.csv`` with one row ``step,tag,value`` per scalar point;
* ``wandb``: :class:`WandbLogger`, a Weights & Biases run (the optional ``wandb`` extra, imported only
  when named): the config, the scalars, the evaluation pictures and Q-value histograms; the replicas of
  a run are runs of one group (the run directory's name), and each resume of a replica is a new run of
  that group. ``WANDB_MODE=offline`` writes only the local run directory (``wandb/`` in the run
  directory; ``wandb sync`` uploads it later). W&B prints nothing on the console.

A backend's interface (:class:`Backend`) is six calls: several scalars of one step, rows of scalars
of several steps, an evaluation's views, a text, flush and close; the config is given when it is made.
"""

from __future__ import annotations

import csv
import html
import io
import math
import os
import secrets
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dqn_transfer.enums import Logger
from dqn_transfer.envs import Game
from dqn_transfer.storage.checkpoint import atomic_write
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.tensorboard import RunLogger, episode_tags

CSV_HEADER = ("step", "tag", "value")
WANDB_PROJECT = "dqn_transfer"  # unless WANDB_PROJECT says otherwise


class Backend(Protocol):
    def scalars(self, points: Sequence[tuple[str, float]], step: int) -> None: ...

    def scalar_rows(self, tags: Sequence[str], steps: np.ndarray, values: np.ndarray, wall_times: np.ndarray) -> None:
        """Row i of ``values`` (every value a number), the points of ``tags`` at ``steps[i]``, logged at
        ``wall_times[i]``."""

    def evaluation_views(self, picture: np.ndarray, q_values: Sequence[np.ndarray], step: int) -> None: ...

    def text(self, tag: str, text: str, step: int = 0) -> None: ...

    def flush(self, durable: bool = False) -> None:
        """Hand what is buffered to the operating system, and with ``durable`` wait until it is on the disk."""

    def close(self) -> None: ...


class PendingRows:
    """Rows of values of fixed tags, a step each, kept in growing arrays until they are written.

    :param width: the values of a row (its tags).
    """

    def __init__(self, width: int) -> None:
        self.steps = np.zeros(64, dtype=np.int64)
        self.wall_times = np.zeros(64)
        self.values = np.zeros((64, width))
        self.count = 0

    def add(self, step: int, values: np.ndarray) -> None:
        if self.count == len(self.steps):  # full: twice the room
            self.steps, self.wall_times, self.values = (
                np.concatenate([column, np.zeros_like(column)]) for column in (self.steps, self.wall_times, self.values)
            )
        self.steps[self.count], self.wall_times[self.count], self.values[self.count] = step, time.time(), values
        self.count += 1

    def take(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows' steps, wall times and values, oldest first, which are no longer pending (views of
        the arrays, valid until the next :meth:`add`)."""
        count, self.count = self.count, 0
        return self.steps[:count], self.wall_times[:count], self.values[:count]


class CsvLogger:
    """``scalars.csv``: the scalars TensorBoard gets, one row ``step,tag,value`` each.

    Long rather than wide: which tags a step has varies (evaluations, episode ends, training points),
    so a row per point needs no header that grows with new tags, appends as the run goes, and reads
    as TensorBoard's own (tag, step, value) points. The rows go to the operating system at each
    :meth:`flush`, so a killed run keeps what it flushed; a resumed run (``purge_step``) first drops the
    rows from that step on, which it logs again, as TensorBoard hides the same events.
    """

    def __init__(self, path: Path, purge_step: int | None = None):
        if purge_step and path.exists():
            self._keep_before(path, purge_step)
        fresh = not path.exists() or path.stat().st_size == 0
        self.file = path.open("a", newline="", encoding="utf-8")
        self.writer = csv.writer(self.file)
        if fresh:
            self.writer.writerow(CSV_HEADER)
            self.file.flush()

    @staticmethod
    def _keep_before(path: Path, purge_step: int) -> None:
        """Rewrite ``path`` (atomically) with its complete rows before ``purge_step``; a last row a
        kill cut short is dropped too."""
        with path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
        out = io.StringIO()
        writer = csv.writer(out)
        writer.writerow(CSV_HEADER)
        for row in rows[1:]:
            try:
                step, tag, value = int(row[0]), row[1], float(row[2])
            except (IndexError, ValueError):
                continue
            if step < purge_step and len(row) == 3:
                writer.writerow((step, tag, repr(value)))
        atomic_write(path, out.getvalue().encode())

    def scalars(self, points: Sequence[tuple[str, float]], step: int) -> None:
        self.writer.writerows((step, tag, repr(float(value))) for tag, value in points)

    def scalar_rows(self, tags: Sequence[str], steps: np.ndarray, values: np.ndarray, wall_times: np.ndarray) -> None:
        self.writer.writerows(
            (step, tag, repr(value))
            for step, row in zip(steps.tolist(), values.tolist())
            for tag, value in zip(tags, row)
        )

    def evaluation_views(self, picture: np.ndarray, q_values: Sequence[np.ndarray], step: int) -> None:
        pass  # scalars only

    def text(self, tag: str, text: str, step: int = 0) -> None:
        pass

    def flush(self, durable: bool = False) -> None:
        self.file.flush()
        if durable:
            os.fsync(self.file.fileno())

    def close(self) -> None:
        self.file.close()


def import_wandb() -> Any:
    try:
        import wandb
    except ImportError:
        raise ImportError(
            "logger=[...,wandb] needs the wandb package: pip install 'dqn-transfer[wandb]' (or pip install wandb)"
        ) from None
    return wandb


class WandbLogger:
    """A Weights & Biases run of one replica: ``group`` the batch's run directory's name, ``name`` the
    replica's; its files in ``RUN/wandb/``. The mode (online, offline, disabled) is W&B's own setting
    (``WANDB_MODE``).

    A resumed replica logs to a new W&B run of the same group, ``<replica>-resumed-<n>`` (the n-th
    resume), whose history starts right after the checkpoint, as the CSV's and TensorBoard's do: W&B
    keeps a run's steps increasing (it drops a point at a step the run has passed, so the resumed run's
    points at the steps the killed run logged after its checkpoint would be lost online), and it does not
    resume offline runs at all (a second offline run of the same id replaces the first one's history when
    synced). The killed run keeps what it logged, including any points after its checkpoint; from the
    resume's first step on, the ``-resumed-<n>`` run's points are the run's. ``RUN/wandb/wandb_id`` lists
    the ids of the replica's W&B runs, one a line, oldest first.

    :param run_dir: the replica's run directory.
    :param group: the W&B group, the batch's run directory's name.
    :param config: the replica's config, as plain data.
    :param resume: whether the replica resumes from a checkpoint.
    :param first_step: a resumed run's first step (its checkpoint's step + 1), for the W&B run's notes.
    """

    def __init__(self, run_dir: RunDir, group: str, config: Mapping[str, Any], resume: bool, first_step: int | None):
        wandb = import_wandb()
        self.wandb = wandb
        run_dir.wandb.mkdir(parents=True, exist_ok=True)
        earlier = run_dir.wandb_id.read_text().split() if resume and run_dir.wandb_id.exists() else []
        run_id = secrets.token_hex(4)  # W&B's ids: lower-case letters and digits
        with run_dir.wandb_id.open("a") as ids:
            ids.write(run_id + "\n")
        name, notes = run_dir.path.name, None
        if resume:
            notes = f"resumed from a checkpoint: logs from step {first_step} on"
            if earlier:
                name = f"{name}-resumed-{len(earlier)}"
                notes += f", after W&B run {earlier[-1]}"
        self.run = wandb.init(
            project=os.environ.get("WANDB_PROJECT") or WANDB_PROJECT,
            group=group,
            name=name,
            notes=notes,
            config=dict(config),
            dir=str(run_dir.path),
            id=run_id,
            reinit="create_new",  # the replicas of a batch are runs of one process
            # W&B's own console lines (a banner per replica's run, its history and summary at the end: 68
            # of a 2-replica run's 73 lines) bury the run's; its files are written all the same.
            settings=wandb.Settings(silent=True),
        )

    def scalars(self, points: Sequence[tuple[str, float]], step: int) -> None:
        self.run.log(dict(points), step=step)

    def scalar_rows(self, tags: Sequence[str], steps: np.ndarray, values: np.ndarray, wall_times: np.ndarray) -> None:
        for step, row in zip(steps.tolist(), values.tolist()):
            self.run.log(dict(zip(tags, row)), step=step)

    def evaluation_views(self, picture: np.ndarray, q_values: Sequence[np.ndarray], step: int) -> None:
        views: dict[str, Any] = {"eval/episode": self.wandb.Image(picture)}
        views.update(
            {f"agent_{i}/q_values": self.wandb.Histogram(values) for i, values in enumerate(q_values) if values.size}
        )
        self.run.log(views, step=step)

    def text(self, tag: str, text: str, step: int = 0) -> None:
        self.run.log({tag: self.wandb.Html(f"<pre>{html.escape(text)}</pre>")}, step=step)

    def flush(self, durable: bool = False) -> None:
        pass  # W&B's own process writes and uploads what run.log handed it

    def close(self) -> None:
        self.run.finish()


class RunLoggers:
    """A replica's logs: the tag vocabulary's helpers, and every backend its ``logger`` list names.

    :param names: the backends (the ``logger`` list).
    :param run_dir: the replica's run directory.
    :param group: the W&B group, the batch's run directory's name.
    :param game: the replica's game, whose team and metrics TensorBoard's layout and hparams name.
    :param config: the replica's config, as plain data.
    :param resume: whether the replica resumes from a checkpoint.
    :param purge_step: a resumed run's first step, from which the killed run's points are dropped.
    """

    def __init__(
        self,
        names: Iterable[Logger | str],
        run_dir: RunDir,
        group: str,
        game: Game,
        config: Mapping[str, Any],
        resume: bool,
        purge_step: int | None = None,
    ):
        self.backends: list[Backend] = []
        self.episode_tags = episode_tags(game.num_agents, game.episode_metrics)
        self.episodes = PendingRows(len(self.episode_tags))
        try:
            for name in dict.fromkeys(Logger(n) for n in names):  # each once, in the given order
                if name is Logger.tensorboard:
                    tensorboard = RunLogger(
                        run_dir.tensorboard,
                        game.num_agents,
                        config,
                        eval_metrics=game.headline_metrics,
                        team_metrics=game.episode_metrics,
                        purge_step=purge_step,
                    )
                    self.backends.append(tensorboard)
                elif name is Logger.csv:
                    self.backends.append(CsvLogger(run_dir.scalars_csv, purge_step=purge_step))
                else:
                    self.backends.append(WandbLogger(run_dir, group, config, resume, purge_step))
        except BaseException:
            self.close()
            raise

    def episode(self, step: int, values: np.ndarray) -> None:
        """A training episode that ended at ``step``: its ``values``, in the order of :attr:`episode_tags`
        (:func:`~dqn_transfer.training.tensorboard.episode_tags`), wait for the next write."""
        self.episodes.add(step, values)

    def _write_episodes(self) -> None:
        """The pending episodes' points to every backend, in one batch: before any later point (W&B
        drops a point at a step it has passed) and at each flush."""
        if self.episodes.count:
            steps, wall_times, values = self.episodes.take()
            for backend in self.backends:
                backend.scalar_rows(self.episode_tags, steps, values, wall_times)

    def scalars(self, values: Iterable[tuple[str, float | None]], step: int) -> None:
        """Several ``(tag, value)`` points of one step; NaNs and Nones (no update yet) are skipped,
        and nothing is logged if none is left."""
        points = [(tag, float(value)) for tag, value in values if value is not None and not math.isnan(float(value))]
        if points:
            self._write_episodes()
            for backend in self.backends:
                backend.scalars(points, step)

    def scalar(self, tag: str, value: float | None, step: int) -> None:
        self.scalars([(tag, value)], step)

    agent_values = staticmethod(RunLogger.agent_values)

    def evaluation_views(self, picture: np.ndarray, q_values: Sequence[np.ndarray], step: int) -> None:
        self._write_episodes()
        for backend in self.backends:
            backend.evaluation_views(picture, q_values, step)

    def text(self, tag: str, text: str, step: int = 0) -> None:
        self._write_episodes()
        for backend in self.backends:
            backend.text(tag, text, step)

    def flush(self, durable: bool = False) -> None:
        """Write the pending episodes and hand everything to the operating system, so a killed run keeps
        it; ``durable`` (at a checkpoint, before its files) also waits until it is on the disk, so what
        a checkpoint covers survives a crash of the machine too."""
        self._write_episodes()
        for backend in self.backends:
            backend.flush(durable)

    def close(self) -> None:
        self._write_episodes()
        for backend in self.backends:
            backend.close()
