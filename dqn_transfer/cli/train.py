"""``python train.py`` / ``dqn-transfer-train``: the Hydra app around the trainer.

It composes the config (``conf/`` + the schema), takes the run's own saved config on ``resume=true``,
finds or pretrains the transfer source, and trains. A user's mistake ends in one ``error:`` line (on
stderr and in the run's log) and exit code 1, never a traceback.
"""

from __future__ import annotations

import logging
import math
import sys
import warnings
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.utils import get_original_cwd
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from dqn_transfer.checkpoint import CheckpointError, load_training_state
from dqn_transfer.config import CONFIG_DIR, ConfigError, TrainConfig, register_configs
from dqn_transfer.run_dir import RunDir
from dqn_transfer.sources import transfer_source
from dqn_transfer.trainer import existing_run_message, train
from dqn_transfer.transfer_mapping import TransferError

log = logging.getLogger("dqn_transfer.train")

USER_ERRORS = (ConfigError, CheckpointError, TransferError)
# What a resumed run may change; everything else is the run's own saved config.
RESUMABLE_KEYS = ("total_steps", "progress", "checkpoint_every", "device", "threads")


def resume_config(run: RunDir, cfg: DictConfig, overrides: list[str]) -> TrainConfig:
    """The saved config of the run being resumed, with the command line's resumable overrides.

    ``resume=true hydra.run.dir=DIR`` alone continues the run as it was configured; an override that
    would change what is being learned (``agent.lr=...``, ``agent=sarsa``) is refused by name.
    """
    _, meta = load_training_state(run.training_state)
    try:
        saved = OmegaConf.merge(OmegaConf.structured(TrainConfig), meta["config"])
    except (KeyError, OmegaConfBaseException) as err:
        raise ConfigError(f"{run.training_state}: its saved config does not fit this version of dqn_transfer "
                          f"({err})") from None
    # Hydra has just written the resume command's composition there; record the run's own instead.
    OmegaConf.save(saved, run.config)
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~")
        if key == "resume" or key.startswith("hydra"):
            continue
        wanted = OmegaConf.select(cfg, key)
        if key in RESUMABLE_KEYS:
            OmegaConf.update(saved, key, wanted)
        elif wanted != (have := OmegaConf.select(saved, key)):
            shown = "" if isinstance(have, DictConfig) else f" ({key}={have})"
            raise ConfigError(f"resume=true: '{override}' differs from the run's own setting{shown}; a resumed "
                              f"run may change only {', '.join(RESUMABLE_KEYS)}")
    saved.resume = True
    OmegaConf.save(saved, run.config)
    return OmegaConf.to_object(saved)  # type: ignore[return-value]


class RefuseExistingRun(Callback):
    """Hydra callback: refuse a new run in a run directory that holds one *before* Hydra rewrites
    its ``.hydra/`` record (the trainer's own check comes after that)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        run = RunDir(config.hydra.run.dir)
        if not config.resume and run.has_run():
            print(f"error: {existing_run_message(run.path)}", file=sys.stderr)
            sys.exit(1)


def log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (e.g. "a layout fixes the map; ignoring ...") as one line of the run's log, not a
    Python warning with a file name and a source line."""
    log.warning("%s", message)


def report_user_error(err: Exception) -> None:
    """One line on stderr and in the run's log file; no traceback for a user's mistake."""
    message = f"error: {err}"
    print(message, file=sys.stderr)
    record = log.makeRecord(log.name, logging.ERROR, __file__, 0, message, None, None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


register_configs()


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="config")
def main(cfg: DictConfig) -> float:
    """Train one run (or one job of a ``-m`` sweep); returns the last evaluation's team return, the
    objective a Hydra sweeper (e.g. Optuna) would optimise."""
    warnings.showwarning = log_warning
    run = RunDir(HydraConfig.get().runtime.output_dir)
    try:
        if cfg.resume and run.has_run():
            config = resume_config(run, cfg, HydraConfig.get().overrides.task)
        else:
            config = OmegaConf.to_object(cfg)
        source = transfer_source(config, Path(get_original_cwd()))
        summary = train(config, run.path, source=source)
    except USER_ERRORS as err:
        report_user_error(err)
        sys.exit(1)
    return float(summary["last_eval"].get("team_return", math.nan))


if __name__ == "__main__":
    main()
