"""The training loop: a run plan -> games + learners -> loop -> logs, evaluations, checkpoints.

One *step* is one joint environment step: every live agent acts once. A run may batch R independent
*replicas* (``replicas.seeds`` x ``replicas.maps``): R games stepped in lockstep and one batched
learner, each replica otherwise a complete run of its own (:class:`~dqn_transfer.training.replica.Replica`,
its own run directory). :meth:`Trainer.run` reads top to bottom:

1. act epsilon-greedily for every live agent (one batched forward for all agents of all replicas);
2. step the games, hand the joint transition to the learner (which stores it and trains);
3. at a replica's episode end: record per-agent and team statistics (written with step 5's points),
   exchange knowledge if due, reset;
4. every ``eval_every`` steps: greedy evaluation on episodes seeded by (seed, step, episode) alone ->
   ``metrics.jsonl``, and to TensorBoard with a picture of its first episode and the agents' Q-values there;
5. every ``LOG_EVERY`` steps: losses, Q means, epsilon and speed to TensorBoard and the progress bar,
   and the episodes' points since the last time, each replica's in one batch;
6. every ``checkpoint_every`` steps, and when a signal asks to stop: a checkpoint of every replica
   (:mod:`dqn_transfer.training.run_state`), its logs on the disk first.

Steps 1-3 on the treasure hunt run compiled, many at a time, with the same numbers: a tabular team's
whole (:mod:`~dqn_transfer.training.tabular_steps`), a DQN team's around its forward passes and gradient
steps (:mod:`~dqn_transfer.training.dqn_steps`); :func:`compiled_steps` says which runs.

The run is planned (validated, its replicas' maps resolved) beforehand, by
:func:`~dqn_transfer.training.plan.plan_run`.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, NoReturn, cast

import numpy as np
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from dqn_transfer import compiled as compiled_kernels
from dqn_transfer.agents import Learner, Transition, UpdateStats, make_replicas
from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.agents.state_index import DenseIndex
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.config import ConfigError, TrainConfig, plain_yaml, to_plain
from dqn_transfer.enums import Algorithm, Logger
from dqn_transfer.envs.game import TreasureHunts
from dqn_transfer.envs.game_batch import GameBatch, game_batch
from dqn_transfer.envs.observation_code import observation_code
from dqn_transfer.evaluation.batched_rollout import evaluate_replicas
from dqn_transfer.evaluation.rollout import EvaluationStopped
from dqn_transfer.exchange import ExchangeMethod, exchange_method
from dqn_transfer.storage.checkpoint import CheckpointError, atomic_write, atomic_write_all
from dqn_transfer.storage.run_dir import RunDir, existing_run_message
from dqn_transfer.timing import Stopwatch
from dqn_transfer.training.dqn_steps import DQNSteps
from dqn_transfer.training.loop_kernels import UpdateWindow
from dqn_transfer.training.plan import RunPlan
from dqn_transfer.training.replica import EpisodeSums, EpsilonSchedule, Replica, evaluation_line, metric_text
from dqn_transfer.training.run_state import encode_checkpoint, load_checkpoint
from dqn_transfer.training.stop import Interrupted, StopRequest
from dqn_transfer.training.tabular_steps import TabularSteps
from dqn_transfer.transfer.warm_start import apply_transfer, lineage_table

log = logging.getLogger("dqn_transfer.train")

LOG_EVERY = 200  # env steps between td_loss / q_mean / epsilon / sps points in TensorBoard

# glibc's mallopt parameters (malloc.h) and the values training sets (see keep_freed_memory).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
TRIM_THRESHOLD = 512 * 2**20
MMAP_THRESHOLD = 32 * 2**20  # glibc's largest (DEFAULT_MMAP_THRESHOLD_MAX on 64-bit)
_allocator_tuned = False

Sources = Sequence[Path | Sequence[Path]]


class WholeLines(tqdm):
    """A tqdm whose ``write`` hands the stream a message and its newline in one write. tqdm's own writes
    them apart, and the jobs of a sweep (or a batch's workers) that share a pipe then glue one job's line
    onto another's."""

    @classmethod
    def write(cls, s: str, file: Any = None, end: str = "\n", nolock: bool = False) -> None:
        super().write(s + end, file=file, end="", nolock=nolock)


def log_above_bars(loggers: list[logging.Logger] | None = None) -> AbstractContextManager[None]:
    """Log lines printed above the progress bar, never glued to it, each as one write (:class:`WholeLines`);
    ``loggers``: the root logger's handlers when None."""
    return logging_redirect_tqdm(loggers, tqdm_class=WholeLines)


class Trainer:
    """Owns one run directory: builds the games and the learner of a plan, runs the loop, writes
    every artefact.

    With several replicas, the run directory holds one complete run directory per replica
    (``seed_<s>`` or ``seed_<s>-map_<m>``), and one batched learner trains them all in lockstep.
    ``sources`` are the checkpoints a ``transfer.enabled`` run starts its target agents from, per
    replica one for all targets or a list with one per target (found or pretrained by
    :mod:`dqn_transfer.sources`).
    """

    def __init__(
        self,
        plan: RunPlan,
        run_dir: Path,
        *,
        sources: Sources | None = None,
        tag: str = "",
        final_dirs: Sequence[Path] | None = None,
        report_step: Callable[[int], None] | None = None,
    ):
        """``report_step``: called with the step at each training-curve point, instead of a progress bar
        (a worker's: :mod:`~dqn_transfer.training.workers`)."""
        config = plan.config
        self.plan, self.config = plan, config
        self.run_dir = RunDir(run_dir)
        self.tag = tag
        # Where each replica's run directory ends up once the caller moves it (a cache entry): the paths
        # the log names, which must exist after the run. None: where it is trained.
        self.final_dirs = [RunDir(path) for path in final_dirs] if final_dirs is not None else None
        self.source_task = plan.source_task
        self.algorithm = Algorithm(config.agent.algorithm)
        games = [replica.new_game() for replica in plan.replicas]
        first = games[0]
        self.learner = make_replicas(
            config.agent,
            first.num_agents,
            first.obs_layout(),
            first.num_actions,
            seeds=[r.config.seed for r in plan.replicas],
            device=config.device,
            threads=config.threads,
            code=observation_code(games),
        )
        # The run's knowledge exchange (its hooks: dqn_transfer.exchange.base); a resumed run then loads its state.
        self.exchange = exchange_method(config)(config.transfer, len(plan.replicas))
        self.exchange.start(self.learner)
        self.report_step = report_step
        # null: someone watches a run started by hand, one replica of it; a sweep's jobs are compared by curves
        pictures = [plan.first_replica + r == 0 and not in_multirun() for r in range(len(plan.replicas))]
        if config.eval_pictures is not None:
            pictures = [config.eval_pictures] * len(plan.replicas)
        per_replica = list(sources) if sources is not None else [None] * len(plan.replicas)
        # every replica's episode
        self.episodes = EpisodeSums(len(games), first.num_agents, first.reward_mode, first.episode_metrics)
        self.replicas = [
            Replica(
                r,
                replica.config,
                replica_dir,
                game,
                cast(Learner, self.learner.replica(r)),
                source,
                self.exchange,
                self.episodes,
                pictures=pictures[r],
            )
            for r, (replica, replica_dir, game, source) in enumerate(
                zip(plan.replicas, plan.replica_dirs(self.run_dir.path), games, per_replica)
            )
        ]
        self.prepared = False  # prepare() ran: the run's start is checked (run() then skips it)
        self.games: GameBatch | None = None  # the replicas' games while the loop runs (built when it starts)
        # Time spent outside the loop proper (what a benchmark subtracts to compare with bare loops).
        self.evaluation_time, self.checkpoint_time = Stopwatch(), Stopwatch()

    @property
    def step(self) -> int:
        return self.replicas[0].counters.step  # the replicas run in lockstep

    # ------------------------------------------------------------------ setup
    def prepare(self) -> None:
        """Resume, or start fresh (with transfer if asked); refuses to overwrite another run. Raises a
        user error for a run that cannot start; ``run`` calls it unless the caller did already."""
        self.prepared = True
        check_start(self.plan, self.run_dir.path)
        if self.config.resume:
            for rep in self.replicas:
                load_checkpoint(rep, self.algorithm)
            steps = sorted({rep.counters.step for rep in self.replicas})
            if len(steps) > 1:
                raise CheckpointError(
                    f"{self.run_dir}: the replicas' checkpoints are at different steps {steps} "
                    "(a checkpoint write was cut short); resume each replica on its own"
                )
            return
        if self.config.transfer.enabled and not self.source_task:
            for rep in self.replicas:
                if rep.source is None:
                    raise ConfigError(
                        "transfer.enabled: the trainer needs the source checkpoint "
                        "(dqn_transfer.sources.resolve.transfer_sources finds or pretrains it)"
                    )
                rep.transfer_info = apply_transfer(
                    rep.config, rep.learner, rep.game, rep.source, list(self.plan.targets)
                )

    def _write_replica_configs(self) -> None:
        """Each replica's own composed config, where the readers of a run directory look for it; and
        the batch's index (a share's workers leave it to the process that split the run)."""
        if self.plan.is_lone_run:
            return
        for rep in self.replicas:
            rep.run_dir.hydra_dir.mkdir(parents=True, exist_ok=True)
            atomic_write(rep.run_dir.config, plain_yaml(rep.plain_config).encode())
        if not self.plan.batch_size:
            write_replicas_index(self.plan, self.run_dir)

    # --------------------------------------------------------------------- loop
    def run(self) -> dict[str, Any]:
        """Train to ``total_steps`` (or continue a resumed run); returns a short summary.

        Raises :class:`~dqn_transfer.training.stop.Interrupted` when SIGINT or SIGTERM stopped it (at
        the end of the step in progress, after a checkpoint there).
        """
        keep_freed_memory()
        with StopRequest() as stop, log_above_bars(), tagged(log, self.tag):
            if not self.prepared:
                self.prepare()
            self.run_dir.path.mkdir(parents=True, exist_ok=True)
            self._write_replica_configs()
            try:
                for rep in self.replicas:
                    rep.open_logs(resume=self.config.resume, group=self._group())
                return self._train(stop)
            finally:
                for rep in self.replicas:
                    rep.close_logs()

    def _train(self, stop: StopRequest) -> dict[str, Any]:
        config, learner, replicas = self.config, self.learner, self.replicas
        for rep in replicas:
            if rep.transfer_info is not None and not config.resume:
                rep.logger.text("transfer/source", json.dumps(rep.transfer_info, indent=2))
                rep.logger.text("transfer/lineage", lineage_table(rep.transfer_info))
        if compiled_kernels.FIRST_COMPILE:
            log.info(
                "compiling the game's kernels (the first run of this code only: later runs load them from the disk)"
            )
        if config.total_steps == 0:
            self.save_checkpoint()
            log.info("total_steps=0: wrote the initial checkpoints to %s", self._where()[0])
            return self._summary()
        # Step 0, or a resumed checkpoint's step whose evaluation was lost:
        due = [
            rep
            for rep in replicas
            if rep.counters.step % config.eval_every == 0 and rep.last_eval_step != rep.counters.step
        ]
        if due and not self.run_evaluation(due, stop):
            self._stop_here(stop)
        for rep in replicas:
            rep.start_episodes()
        self.games = games = game_batch([rep.game for rep in replicas], [rep.env_rng for rep in replicas])
        num_rows = games.num_replicas * games.num_agents
        schedule = EpsilonSchedule.joined([rep.epsilon_schedule() for rep in replicas])
        window = UpdateWindow(num_rows)  # the updates' statistics since the last training-curve point
        compiled = compiled_steps(learner, games, self.exchange, schedule, self.episodes, window)
        bar = tqdm(
            total=config.total_steps,
            initial=self.step,
            # Only on a terminal: in a captured stream (a file, a pipe, a sweep's parallel jobs sharing
            # one) a bar's carriage returns glue other lines onto it, and nobody watches it there. A
            # worker reports its steps to the bar of the process that started it.
            disable=not config.progress or not sys.stderr.isatty() or self.report_step is not None,
            unit="step",
            dynamic_ncols=True,
            file=sys.stderr,
        )
        sps_clock, sps_step = time.perf_counter(), self.step
        while self.step < config.total_steps:
            if compiled is not None:
                # 1-3. the same steps compiled, up to the next step 4-6 act on
                last = next_boundary(self.step, config, replicas[0].counters.next_checkpoint)
                for ended_at, r, values in compiled.run(self.step, last):
                    replicas[r].record_episode(ended_at, values)
                step = last
                for rep in replicas:
                    rep.counters.step = step
            else:
                step = self._step(games, schedule, window)
            # 4. evaluation
            if step % config.eval_every == 0:
                self.run_evaluation(replicas, stop)  # stopped unfinished: the checkpoint below, then out
            # 5. training curves and the progress bar
            if step % LOG_EVERY == 0 or step == config.total_steps:
                now = time.perf_counter()
                sps = (step - sps_step) / max(now - sps_clock, 1e-9)
                sps_clock, sps_step = now, step
                means = window.means()
                for rep in replicas:
                    rep.log_training(
                        sps, None if means is None else UpdateStats(*(column[rep.rows] for column in means))
                    )
                recent = [r for rep in replicas for r in rep.episode.recent_team_returns]
                bar.set_postfix(
                    team_return=f"{np.mean(recent):.1f}" if recent else "-",
                    eps=f"{schedule.at(step - 1).mean():.2f}",  # the last step's
                    sps=f"{sps:.0f}",
                    refresh=False,
                )
                bar.update(step - bar.n)
                if self.report_step is not None:
                    self.report_step(step)
            # 6. checkpoint when due, and at a signal (a checkpoint between two steps resumes exactly)
            if step >= replicas[0].counters.next_checkpoint or stop.signum is not None:
                if step < config.total_steps or stop.signum is not None:  # else written once, after the loop
                    self.save_checkpoint()
                for rep in replicas:
                    while rep.counters.next_checkpoint <= step:
                        rep.counters.next_checkpoint += config.checkpoint_every
                if stop.signum is not None:
                    bar.close()
                    raise Interrupted(stop.signum, step, self.run_dir.path)
        bar.close()
        due = [rep for rep in replicas if rep.last_eval_step != self.step]  # not twice when resuming a finished run
        if due and not self.run_evaluation(due, stop):
            self._stop_here(stop)
        self.save_checkpoint()
        rep = replicas[0]
        checkpoints, logdir = self._where()
        watched = Logger.tensorboard in [Logger(name) for name in self.config.logger]
        log.info(
            "done: %d steps, %s; last eval %s; checkpoints in %s; "
            + ("watch with `tensorboard --logdir %s`" if watched else "logs beside them: %s"),
            self.step,
            self._episodes_text(),
            self._last_eval_text(),
            checkpoints,
            logdir if watched else ", ".join(Logger(name).value for name in self.config.logger),
        )
        return self._summary()

    def _step(self, games: GameBatch, schedule: EpsilonSchedule, window: UpdateWindow) -> int:
        """Steps 1-3 of the loop, one joint step: act, step the games, learn, add to the episodes' sums,
        log the ended episodes and restart their games. Returns the step after it."""
        learner, replicas = self.learner, self.replicas
        num_rows = games.num_replicas * games.num_agents
        # 1. act: one batched forward for every agent of every replica
        step = self.step
        epsilon = schedule.at(step)
        live = games.live.reshape(num_rows)
        obs = games.obs.reshape(num_rows, -1)
        actions = learner.act(obs, live, epsilon=epsilon)
        # 2. step the games and learn
        outcome = games.step(actions.reshape(games.num_replicas, games.num_agents))
        transition = Transition(
            obs,
            actions,
            outcome.rewards.reshape(num_rows),
            outcome.next_obs.reshape(num_rows, -1),
            outcome.terminated.reshape(num_rows),
            outcome.truncated.reshape(num_rows),
            live,
        )
        window.add(*learner.update(transition, step + 1))
        self.episodes.add(outcome.rewards, live.reshape(outcome.rewards.shape), outcome.trap)
        for rep in replicas:
            rep.counters.step = step + 1
        self.exchange.after_step(transition, outcome.bounced)
        # 3. where an episode ended: log it, exchange knowledge; then the next episodes
        ended = np.flatnonzero(outcome.episode_end)
        if ended.size:
            values = self.episodes.ended_values(ended, outcome.episode_treasures)  # all replicas' at once
            for r, row in zip(ended.tolist(), values):
                replicas[r].end_episode(row)
        games.reset(outcome.episode_end)
        return step + 1

    def _group(self) -> str:
        """The name the run's replicas share in W&B: its run directory's, where the run ends up."""
        if self.final_dirs is None:
            return self.run_dir.path.name
        return (self.final_dirs[0].path if len(self.final_dirs) == 1 else self.final_dirs[0].path.parent).name

    def _where(self) -> tuple[str, str]:
        """The run's checkpoints and its TensorBoard logdir as the log names them: where the run ends
        up (``final_dirs``), never a work directory the caller renames away."""
        if self.final_dirs is None:
            if len(self.replicas) == 1:
                return str(self.replicas[0].run_dir.checkpoints), str(self.replicas[0].run_dir.tensorboard)
            return f"{self.run_dir}/*/checkpoints", str(self.run_dir)
        if len(self.final_dirs) == 1:
            return str(self.final_dirs[0].checkpoints), str(self.final_dirs[0].tensorboard)
        parent = self.final_dirs[0].path.parent
        return ", ".join(str(run.checkpoints) for run in self.final_dirs), str(parent)

    def run_evaluation(self, replicas: Sequence[Replica], stop: StopRequest) -> bool:
        """Greedy evaluation of ``replicas`` at their current step, all played as one batch; False when a stop
        was asked for before it finished (then nothing is recorded: a resumed run plays it again, whole)."""
        with self.evaluation_time:
            try:
                evaluations = evaluate_replicas(
                    self.learner if len(replicas) == len(self.replicas) else None,  # its rows are all replicas'
                    [rep.learner for rep in replicas],
                    [rep.eval_game for rep in replicas],
                    self.config.eval_episodes,
                    [rep.config.seed for rep in replicas],
                    [rep.counters.step for rep in replicas],
                    [rep.pictures for rep in replicas],
                    stop.asked,
                )
            except EvaluationStopped:
                log.warning("the evaluation at step %d was stopped unfinished; a resumed run plays it again", self.step)
                return False
            for rep, evaluation in zip(replicas, evaluations):
                rep.record_evaluation(*evaluation)
            records = [evaluation.record for evaluation in evaluations]
            log.info(evaluation_line(self.step, records, replicas[0].game.headline_metrics))
        return True

    def _stop_here(self, stop: StopRequest) -> NoReturn:
        """A checkpoint at the current step, then :class:`~dqn_transfer.training.stop.Interrupted` (a stop asked
        for during an evaluation before or after the loop)."""
        assert stop.signum is not None  # only a signal stops an evaluation
        self.save_checkpoint()
        raise Interrupted(stop.signum, self.step, self.run_dir.path)

    def save_checkpoint(self) -> None:
        """Every replica's agent files (for sharing) and resume state, which alone is read on resume.

        The replicas' logs are on the disk first, so whatever a checkpoint covers is logged, whatever
        stops the run after it. All files are written before any replaces its predecessor, the resume
        states last: a failed write leaves the previous checkpoints whole.
        """
        with self.checkpoint_time:
            for rep in self.replicas:
                rep.logger.flush(durable=True)
            agent_files: dict[Path, bytes] = {}
            state_files: dict[Path, bytes] = {}
            for r, rep in enumerate(self.replicas):
                game_state = self.games.state_dict(r) if self.games is not None else None
                files, state_path, state = encode_checkpoint(rep, self.algorithm, self.source_task, game_state)
                agent_files.update(files)
                state_files[state_path] = state
            atomic_write_all({**agent_files, **state_files})

    # ------------------------------------------------------------------ summary
    def _episodes_text(self) -> str:
        """The done line's episodes: a lone run's count, or the replicas' mean [min, max]."""
        counts = [rep.counters.episodes for rep in self.replicas]
        if len(counts) == 1:
            return f"{counts[0]} episodes"
        return f"{np.mean(counts):.1f} [{min(counts)}, {max(counts)}] episodes a replica"

    def _last_eval_text(self) -> str:
        """The done line's last evaluation: what the game measures, a lone run's or the replicas' mean."""
        game = self.replicas[0].game
        last = self.replicas[0].last_eval if len(self.replicas) == 1 else self._mean_last_eval()
        shown = ", ".join(f"{key} {metric_text(key, last[key])}" for key in game.evaluation_metrics if key in last)
        return shown if len(self.replicas) == 1 else f"(mean of {len(self.replicas)} replicas) {shown}"

    def _mean_last_eval(self) -> dict[str, float]:
        return {
            key: float(np.mean([rep.last_eval[key] for rep in self.replicas])) for key in self.replicas[0].last_eval
        }

    def _summary(self) -> dict[str, Any]:
        lone = self.replicas[0]
        return {
            "step": self.step,
            "episodes": lone.counters.episodes,
            # A lone run's last evaluation; with replicas the mean over them, each replica's in "replicas".
            "last_eval": lone.last_eval if len(self.replicas) == 1 else self._mean_last_eval(),
            "replicas": [
                {
                    "run_dir": str(rep.run_dir),
                    "seed": rep.config.seed,
                    "map_seed": rep.config.env.map_seed,
                    "episodes": rep.counters.episodes,
                    "last_eval": rep.last_eval,
                }
                for rep in self.replicas
            ],
            # Seconds spent evaluating and checkpointing (wall, CPU): not part of the loop proper.
            "overhead": {
                "wall": self.evaluation_time.wall + self.checkpoint_time.wall,
                "cpu": self.evaluation_time.cpu + self.checkpoint_time.cpu,
            },
        }


def train(
    plan: RunPlan,
    run_dir: Path,
    *,
    sources: Sources | None = None,
    tag: str = "",
    final_dirs: Sequence[Path] | None = None,
) -> dict[str, Any]:
    """Run (or resume) the planned run (or batch of replicas) into ``run_dir``; returns a short summary.

    ``tag`` (e.g. ``[pretraining source]``) starts every line the run logs, so that the runs before a
    run (its source's pretraining, its curriculum's stages) are told apart from it. ``final_dirs``: where
    the caller moves each replica's directory afterwards (a cache entry), the paths the log then names.
    """
    return Trainer(plan, run_dir, sources=sources, tag=tag, final_dirs=final_dirs).run()


def check_start(plan: RunPlan, run_dir: Path) -> None:
    """Refuse, in one line, a start that ``run_dir`` does not allow: ``resume=true`` where a replica holds
    no checkpoint, a fresh run where one holds a run already."""
    dirs = [RunDir(path) for path in plan.replica_dirs(run_dir)]
    if plan.config.resume:
        missing = [run for run in dirs if not run.has_run()]
        if missing:
            raise ConfigError(
                f"resume=true but {missing[0]} holds no {missing[0].training_state.name}: pass the run "
                "directory to resume with hydra.run.dir=PATH"
            )
    elif held := [run for run in dirs if run.has_run()]:
        raise ConfigError(existing_run_message(held[0]))


def write_replicas_index(plan: RunPlan, run_dir: RunDir) -> None:
    """A batch's index of its replicas' directories, with the batch's own config: what resume=true on
    the batch directory continues with."""
    index = {"replicas": [replica.name for replica in plan.replicas], "config": to_plain(plan.config)}
    atomic_write(run_dir.replicas_index, (json.dumps(index, indent=2) + "\n").encode())


def compiled_steps(
    learner: Learner,
    games: GameBatch,
    exchange: ExchangeMethod,
    schedule: EpsilonSchedule,
    sums: EpisodeSums,
    window: UpdateWindow,
) -> TabularSteps | DQNSteps | None:
    """The compiled steps of this run, None where they do not cover it. They step treasure hunts as one
    batch, with no exchange that acts inside the loop, and a tabular learner with dense tables and no
    advice, or a DQN learner with per-agent replay (not VDN's joint one)."""
    if not isinstance(games, TreasureHunts) or exchange.in_loop:
        return None
    if isinstance(learner, TabularLearner) and isinstance(learner.index, DenseIndex) and learner.advice is None:
        return TabularSteps(learner, games, schedule, sums, window)
    if isinstance(learner, BatchedDQN) and not learner.replay.joint and learner.shared_experience is None:
        return DQNSteps(learner, games, schedule, sums, window)
    return None


def next_boundary(step: int, config: TrainConfig, next_checkpoint: int) -> int:
    """The first step after ``step`` at which the loop evaluates, logs a training-curve point, takes a
    checkpoint or ends."""
    return min(
        config.total_steps,
        (step // config.eval_every + 1) * config.eval_every,
        (step // LOG_EVERY + 1) * LOG_EVERY,
        max(next_checkpoint, step + 1),
    )


def in_multirun() -> bool:
    """Whether this process runs a job of a Hydra multirun (``-m``: a sweep, whose runs are compared by
    their curves rather than watched one by one)."""
    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def keep_freed_memory() -> bool:
    """Let glibc's malloc keep the memory a process frees, once per process (True if it was set).

    A learner's update allocates and frees the same large temporaries (batches, activations,
    gradients) at every step. With glibc's defaults each of them above the mmap threshold is mapped
    and unmapped again, and freed heap memory above the trim threshold is given back to the system,
    so every update pays for fresh pages in the kernel (13-24 s of a 10-replica Double DQN job).
    Raising both thresholds keeps the freed memory for the next update; no result changes. Elsewhere
    than Linux with glibc this does nothing.
    """
    global _allocator_tuned
    if _allocator_tuned:
        return False
    _allocator_tuned = True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 (glibc only: another libc's mallopt may mean something else)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) & bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))


class _Tag(logging.Filter):
    def __init__(self, tag: str) -> None:
        super().__init__()
        self.tag = tag + " "

    def filter(self, record: logging.LogRecord) -> bool:
        record.msg = self.tag + str(record.msg)
        return True


@contextlib.contextmanager
def tagged(logger: logging.Logger, tag: str) -> Iterator[None]:
    """``tag`` before every line ``logger`` logs meanwhile (nothing for an empty tag)."""
    if not tag:
        yield
        return
    tag_filter = _Tag(tag)
    logger.addFilter(tag_filter)
    try:
        yield
    finally:
        logger.removeFilter(tag_filter)
