"""``python train.py`` / ``dqn-transfer-train``: the Hydra app around the trainer.

It refuses keys outside the schema before Hydra composes anything, claims the run directory (an
exclusive lock; never a directory that holds another run), takes the run's own saved config on
``resume=true``, finds or pretrains the transfer source, and trains. A user's mistake ends in one
``error:`` line and exit code 1, never a traceback, and leaves nothing behind that was not there
before. SIGINT / SIGTERM stop the run after the step in progress, with a checkpoint (exit 130 / 143).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
import sys
import warnings
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from hydra.utils import get_original_cwd
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from dqn_transfer.analysis.runs import EvaluationError, run_objective
from dqn_transfer.cli.console import exit_with
from dqn_transfer.config import (
    CONFIG_DIR,
    ConfigError,
    TrainConfig,
    register_configs,
)
from dqn_transfer.config.help import help_text
from dqn_transfer.config.overrides import check_overrides, open_mapping_overrides
from dqn_transfer.sources.curriculum import curriculum_sources
from dqn_transfer.sources.resolve import transfer_sources
from dqn_transfer.storage.checkpoint import load_training_state
from dqn_transfer.storage.run_dir import RunClaim, RunDir, RunDirError, file_in_the_way
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.stop import Interrupted
from dqn_transfer.training.workers import USER_ERRORS, trainer_for

log = logging.getLogger("dqn_transfer.train")

# What a resumed run may change; everything else is the run's own saved config.
RESUMABLE_KEYS = (
    "total_steps",
    "progress",
    "checkpoint_every",
    "device",
    "threads",
    "eval_pictures",
    "objective",
    "logger",
    "replicas.workers",
)


# ------------------------------------------------------------------------------------ the run directory


class ClaimRunDir(Callback):
    """Hydra callback: claim the run directory *before* Hydra writes its ``.hydra/`` record there (a
    multirun job's: just after) —
    refuse a directory in use by another process, or holding another run (unless resuming it), or
    under a regular file. The claim is kept for the app (``ClaimRunDir.claim``), which undoes it when
    the run is refused."""

    claim: RunClaim | None = None
    requeued = False  # this multirun job's directory holds its own earlier attempt's checkpoint

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._take(RunDir(named_dir(config, "run")), resume=config.resume, fresh=False)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep = Path(named_dir(config, "sweep"))
        if (file := file_in_the_way(sweep)) is not None:
            _exit_with(
                RunDirError(
                    f"cannot use {sweep} as a sweep directory: {file} is a file (choose another hydra.sweep.dir)"
                )
            )
        used = sorted(d.name for d in sweep.iterdir() if d.is_dir() and RunDir(d).holds_run()) if sweep.is_dir() else []
        if used and not config.resume:  # resume=true continues the sweep: each job where it stopped
            _exit_with(
                RunDirError(
                    f"{sweep} already holds the runs of a sweep ({', '.join(used[:5])}"
                    f"{', ...' if len(used) > 5 else ''}); choose another hydra.sweep.dir, or continue it: resume=true"
                )
            )

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        if config.hydra.mode != RunMode.MULTIRUN:
            return
        # Hydra has just made this job's directory and written its .hydra/ record and log there. A sweep
        # directory that holds runs is refused before any job starts, so a job directory that holds
        # more holds this very job's earlier attempt, stopped and requeued (submitit does so on a
        # SLURM preemption or timeout). With a checkpoint it is continued from there; without one,
        # what it left (evaluations, events) is cleared and the job starts afresh.
        run = RunDir(config.hydra.runtime.output_dir)
        requeued = run.has_run()
        if not requeued:
            leftovers = (run.tensorboard, run.scalars_csv, run.wandb, run.checkpoints, run.replicas_index, run.metrics)
            for leftover in (*leftovers, *run.replica_dirs()):
                shutil.rmtree(leftover) if leftover.is_dir() else leftover.unlink(missing_ok=True)
        ClaimRunDir.requeued = requeued
        self._take(run, resume=config.resume or requeued, fresh=not requeued)

    @classmethod
    def _take(cls, run: RunDir, resume: bool, fresh: bool) -> None:
        if cls.claim is not None:  # the previous job of a sequential sweep is over
            cls.claim.release()
        claim = RunClaim(run)
        try:
            claim.acquire(resume=resume, fresh=fresh)
        except RunDirError as err:
            _exit_with(err)
        cls.claim = claim


def named_dir(config: DictConfig, mode: str) -> str:
    """``hydra.run.dir`` (``mode`` run) or ``hydra.sweep.dir`` (sweep); an empty one is refused: Hydra would write
    the run into the launch directory (a repository's root, say) among its files."""
    path = str(config.hydra[mode].dir)
    if not path.strip():
        _exit_with(
            RunDirError(
                f"hydra.{mode}.dir is empty, which would write the {mode} into the launch directory: name a "
                f"directory, or leave hydra.{mode}.dir out for one under outputs/"
            )
        )
    return path


def _exit_with(err: Exception, code: int = 1) -> None:
    print(f"error: {err}", file=sys.stderr)
    sys.exit(code)


def resume_config(run: RunDir, cfg: DictConfig, overrides: list[str], recorded: bytes | None = None) -> TrainConfig:
    """The saved config of the run being resumed, with the command line's resumable overrides.

    ``resume=true hydra.run.dir=DIR`` alone continues the run as it was configured; an override that
    would change what is being learned (``agent.lr=...``, ``agent=sarsa``) is refused by name, and so is a
    resume state that is another run's than the directory's own ``recorded`` config (a file copied in).
    """
    # A run of replicas keeps the batch's config in its index; a lone run in its resume state.
    replicas = run.replicas_index.exists()
    source = run.replicas_index if replicas else run.training_state
    try:
        meta = json.loads(source.read_text()) if replicas else load_training_state(source)[1]
        saved = OmegaConf.merge(OmegaConf.structured(TrainConfig), meta["config"])
    except (OSError, ValueError, KeyError, TypeError, OmegaConfBaseException) as err:
        raise ConfigError(f"{source}: its saved config does not fit this version of dqn_transfer ({err})") from None
    if recorded is not None:
        check_same_run(source, saved, run.config, recorded)
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~")
        if key == "resume" or key.startswith("hydra"):
            continue
        wanted = OmegaConf.select(cfg, key)
        if key == "total_steps" and wanted < saved.total_steps:
            raise ConfigError(
                f"resume=true: total_steps={wanted} is below the run's own total_steps={saved.total_steps}; "
                "a resume may keep or extend it (a shorter run is a new run, or the run's checkpoint at that step)"
            )
        if key in RESUMABLE_KEYS:
            OmegaConf.update(saved, key, wanted)
        elif wanted != (have := OmegaConf.select(saved, key)):
            shown = "" if isinstance(have, DictConfig) else f" ({key}={have})"
            raise ConfigError(
                f"resume=true: '{override}' differs from the run's own setting{shown}; a resumed "
                f"run may change only {', '.join(RESUMABLE_KEYS)}"
            )
    saved.resume = True
    # Hydra has just written the resume command's composition there; record the run's own instead.
    OmegaConf.save(saved, run.config)
    return OmegaConf.to_object(saved)  # type: ignore[return-value]


# What a run is: its game, its team and its learner. A resume state that differs from its directory's own config
# in one of these belongs to another run, whatever else agrees.
RUN_IDENTITY = ("env.factory", "env.kwargs", "env.size", "env.num_treasures", "env.num_agents", "agent.algorithm")


def check_same_run(source: Path, saved: Any, config_file: Path, recorded: bytes) -> None:
    """Refuse the resume state ``source`` (its config ``saved``) when the run directory's own config, ``recorded``
    in ``config_file`` before this resume, is of another game, team or learner (:data:`RUN_IDENTITY`).

    :param source: the resume state (or a batch's index) read.
    :param saved: its config.
    :param config_file: the run directory's config record.
    :param recorded: that record's text as the run left it.
    """
    try:
        own = plain_config(OmegaConf.create(recorded.decode()))
    except (ValueError, OmegaConfBaseException):
        return  # a record this version cannot read says nothing against the state
    theirs = plain_config(saved)
    for key in RUN_IDENTITY:
        section, name = key.split(".")
        if (state := theirs[section][name]) != (record := own[section][name]):
            shown = lambda value: "null" if value is None else value  # noqa: E731
            raise ConfigError(
                f"resume=true: {source} is another run's ({key}={shown(state)}) than this directory's "
                f"({key}={shown(record)} in {config_file}); resume the run it came from, or put back this run's own"
            )


def plain_config(data: Any) -> dict[str, Any]:
    """A run's config (a mapping, or the config itself) on the schema, as plain data (enums by name)."""
    merged = OmegaConf.merge(OmegaConf.structured(TrainConfig), data)
    return OmegaConf.to_container(merged, resolve=True, enum_to_str=True)  # type: ignore[return-value]


# ------------------------------------------------------------------------------------ logging


def log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (e.g. "a layout fixes the map; ignoring ...") as one line of the run's log, not a
    Python warning with a file name and a source line."""
    log.warning("%s", message)


class JobTag(logging.Filter):
    """``[job N]`` before every line of a multirun job, so parallel jobs' lines can be told apart."""

    def __init__(self, num: int) -> None:
        super().__init__()
        self.tag = f"[job {num}] "

    def filter(self, record: logging.LogRecord) -> bool:
        if not str(record.msg).startswith(self.tag):
            record.msg = self.tag + str(record.msg)
        return True


def report_user_error(err: Exception) -> None:
    """One line on stderr and in the run's log file; no traceback for a user's mistake."""
    message = f"error: {err}"
    print(message, file=sys.stderr)
    record = log.makeRecord(log.name, logging.ERROR, __file__, 0, message, (), None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


def leave_nothing_behind(claim: RunClaim | None) -> None:
    """Close the run's log file and remove what this run added to its directory."""
    if claim is None:
        return
    root = logging.getLogger()
    for handler in list(root.handlers):
        if isinstance(handler, logging.FileHandler):
            handler.close()
            root.removeHandler(handler)
    claim.undo()


class HeldBack(logging.Filter):
    """Keeps the log lines of a run's start (a requeued job's note, ``resumed ... at step N``, a warm start's
    source) from the root logger's handlers until ``announce`` has named the run directory, so that line is
    every run's first; a run refused meanwhile never says them (its one line is its ``error:``). A
    context manager: on leaving it, whatever is still held is dropped."""

    def __init__(self) -> None:
        super().__init__()
        self.handlers = list(logging.getLogger().handlers)
        self.held: list[logging.LogRecord] = []

    def __enter__(self) -> HeldBack:
        for handler in self.handlers:
            handler.addFilter(self)
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()

    def filter(self, record: logging.LogRecord) -> bool:
        if not self.held or self.held[-1] is not record:  # one record passes every handler in turn
            self.held.append(record)
        return False

    def release(self) -> list[logging.LogRecord]:
        """Stop holding; returns the lines held so far (once: a second call returns none)."""
        for handler in self.handlers:
            handler.removeFilter(self)
        held, self.held = self.held, []
        return held


def announce(run: RunDir, caught: list[warnings.WarningMessage], held: HeldBack) -> None:
    """The run has started: name its directory, then the warnings its planning gave and the lines held
    back until now."""
    earlier = held.release()
    log.info("run directory: %s", run)
    for warning in caught:
        log_warning(warning.message, warning.category, warning.filename, warning.lineno)
    for record in earlier:
        logging.getLogger().handle(record)


# ------------------------------------------------------------------------------------ the app


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="config")
def app(cfg: DictConfig) -> float:
    """Train one run (or one job of a ``-m`` sweep); returns its ``objective`` (the last evaluation's team
    return, or the mean of all its evaluations'; over a run's replicas, their mean), what a Hydra
    sweeper (Optuna: docs/integrations.md) optimises."""
    warnings.showwarning = log_warning
    hydra_config = HydraConfig.get()
    if hydra_config.mode == RunMode.MULTIRUN:
        for handler in logging.getLogger().handlers:
            handler.addFilter(JobTag(hydra_config.job.num))
    run = RunDir(hydra_config.runtime.output_dir)
    claim = ClaimRunDir.claim
    try:
        with HeldBack() as held:
            if (cfg.resume or ClaimRunDir.requeued) and run.has_run():
                if ClaimRunDir.requeued:
                    log.info("this job ran before and was stopped (requeued): resuming it from its last checkpoint")
                recorded = claim.recorded_config() if claim is not None else None
                config = resume_config(run, cfg, hydra_config.overrides.task, recorded)
            else:
                config = OmegaConf.to_object(cfg)  # type: ignore[assignment]
                if hydra_config.mode == RunMode.MULTIRUN and config.resume:
                    config = dataclasses.replace(config, resume=False)  # a continued sweep's job without a checkpoint
            with warnings.catch_warnings(record=True) as caught:  # said once the plan holds, never before a refusal
                plan = plan_run(config)
            # Announced once the run really starts: before a transfer source's pretraining or a curriculum's
            # stages (which can take minutes), else once the trainer has checked the run's start.
            if plan.chain:
                announce(run, caught, held)
            launch_dir = Path(get_original_cwd())
            sources = (
                curriculum_sources(plan, launch_dir) if config.curriculum.stages else transfer_sources(plan, launch_dir)
            )
            trainer = trainer_for(plan, run.path, sources=sources)
            trainer.prepare()
            if not plan.chain:
                announce(run, caught, held)
        trainer.run()
    except USER_ERRORS as err:
        report_user_error(err)
        leave_nothing_behind(claim)  # a refused run
        sys.exit(1)
    except Interrupted as stop:
        if stop.run_dir.resolve() == run.path.resolve():
            log.warning(
                "interrupted at step %d; resume with: python train.py resume=true hydra.run.dir=%s", stop.step, run
            )
        elif config.curriculum.stages:  # a stage before this run, which never started
            log.warning(
                "interrupted in a curriculum stage, kept at its last checkpoint in %s; run the command "
                "again to resume it",
                stop.run_dir,
            )
            leave_nothing_behind(claim)
        else:  # the source's pretraining was interrupted; it keeps nothing, and this run never started
            log.warning("interrupted while pretraining the transfer source (nothing kept); run the command again")
            leave_nothing_behind(claim)
        sys.exit(stop.exit_code)
    except KeyboardInterrupt:
        resumable = run.has_run()
        log.warning(
            "stopped at once%s",
            f"; resume from the last checkpoint with: python train.py resume=true hydra.run.dir={run}"
            if resumable
            else " before any checkpoint",
        )
        if not resumable and not run.has_metrics():
            leave_nothing_behind(claim)  # nothing worth keeping: no stub
        sys.exit(130)
    # the objective is read from the run's evaluations, as anyone analysing it would
    try:
        return run_objective(run.path, config.objective.value)
    except EvaluationError:
        return math.nan  # a run stopped before its first evaluation


def main() -> None:
    """The command line: ``--help`` (the menu and every key's description), unknown keys refused
    first, then the Hydra app."""
    if {"--help", "-h"} & set(sys.argv[1:]):
        exit_with(print_help)
    try:
        check_overrides(sys.argv[1:])
    except ConfigError as err:
        _exit_with(err)
    register_configs()  # the schemas conf/config.yaml's defaults list names
    sys.argv[1:] = open_mapping_overrides(sys.argv[1:])
    app()


def print_help() -> int:
    print(help_text(program_name()))
    return 0


def program_name() -> str:
    """The command as the user typed it: ``python train.py``, ``python -m dqn_transfer.cli.train`` or
    ``dqn-transfer-train``."""
    script = Path(sys.argv[0])
    if script.resolve() == Path(__file__).resolve():
        return f"python -m {__spec__.name}" if __spec__ else f"python {sys.argv[0]}"
    return f"python {sys.argv[0]}" if script.suffix == ".py" else script.name


if __name__ == "__main__":
    main()
