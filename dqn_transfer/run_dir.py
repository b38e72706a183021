"""The layout of a run directory, owned here: every writer and reader goes through :class:`RunDir`.

::

    RUN/
      .hydra/config.yaml      the composed config (Hydra writes it; resume rewrites it with the run's own)
      .hydra/overrides.yaml   the command line's overrides
      metrics.jsonl           one greedy evaluation per line
      train.log               the run's log
      tb/                     TensorBoard event files
      checkpoints/agent_{i}.safetensors     one file per agent, shareable on its own
      checkpoints/training_state.safetensors  what resume needs besides the agents

The module imports nothing of the package, so the checkpoint files, the trainer and the analysis
can all use it.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HYDRA_DIR = ".hydra"
CONFIG_FILE = "config.yaml"
OVERRIDES_FILE = "overrides.yaml"
METRICS_FILE = "metrics.jsonl"
LOG_FILE = "train.log"
TENSORBOARD_DIR = "tb"
CHECKPOINTS_DIR = "checkpoints"
TRAINING_STATE_FILE = "training_state.safetensors"
AGENT_FILE_GLOB = "agent_*.safetensors"


def agent_file_name(index: int) -> str:
    return f"agent_{index}.safetensors"


def natural_key(path: str | os.PathLike) -> list[Any]:
    """Sort ``agent_2`` before ``agent_10`` and Hydra job ``2`` before ``10``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", str(path))]


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
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS_DIR

    @property
    def training_state(self) -> Path:
        return self.checkpoints / TRAINING_STATE_FILE

    def agent_checkpoint(self, index: int) -> Path:
        return self.checkpoints / agent_file_name(index)

    def has_run(self) -> bool:
        """Whether a run has checkpointed here (what resume continues and a new run must not overwrite)."""
        return self.training_state.exists()

    def has_metrics(self) -> bool:
        return self.metrics.is_file()
