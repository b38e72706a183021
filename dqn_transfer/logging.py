"""TensorBoard logging with the tag names other tools rely on.

Per agent: ``agent_{i}/episodic_return``, ``agent_{i}/episodic_length``, ``agent_{i}/td_loss``,
``agent_{i}/q_mean``, and the histogram ``agent_{i}/q_values`` (at each evaluation: the Q-values of
every observation the agent acted on in the evaluation's first episode).  Team: ``team/return``,
``team/treasures_collected``, ``team/trap_rate``.  Evaluation: ``eval/team_return``,
``eval/success_rate``, ``eval/trap_rate``, and the image ``eval/episode`` (the first episode's last
frame with every agent's trail).  Training: ``train/epsilon``, ``train/sps``.
A custom-scalars layout overlays the agents' curves in one chart each; the flattened config goes to
the hparams plugin (so runs of a sweep can be compared in its table) and, as YAML, to the text plugin.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from torch.utils.tensorboard import SummaryWriter
from torch.utils.tensorboard.summary import hparams

AGENT_TAGS = ("episodic_return", "episodic_length", "td_loss", "q_mean")


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"agent": {"lr": 1e-3}}`` -> ``{"agent.lr": 1e-3}``; lists become JSON strings."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, f"{name}."))
        elif isinstance(value, (list, tuple)):
            flat[name] = json.dumps(list(value))
        else:
            flat[name] = value
    return flat


class RunLogger:
    """A thin SummaryWriter wrapper that owns the tag vocabulary."""

    def __init__(self, tb_dir: Path, num_agents: int, config: Mapping[str, Any], purge_step: int | None = None):
        self.writer = SummaryWriter(log_dir=str(tb_dir), purge_step=purge_step)
        self.num_agents = num_agents
        if not purge_step:  # a resumed run already has its layout, hparams and text
            self._write_layout()
            self._write_config(config)

    def _write_layout(self) -> None:
        agents = range(self.num_agents)
        per_agent = {
            tag: ["Multiline", [f"agent_{i}/{tag}" for i in agents]] for tag in AGENT_TAGS
        }
        team = {
            "return": ["Multiline", ["team/return", "eval/team_return"]],
            "treasures and traps": ["Multiline", ["team/treasures_collected", "team/trap_rate"]],
            "eval success and trap rates": ["Multiline", ["eval/success_rate", "eval/trap_rate"]],
        }
        self.writer.add_custom_scalars({"agents": per_agent, "team": team})

    def _write_config(self, config: Mapping[str, Any]) -> None:
        flat = flatten(config)
        hparam_values = {
            key: value for key, value in flat.items() if isinstance(value, (int, float, str, bool))
        }
        hparam_values.update({key: "null" for key, value in flat.items() if value is None})
        experiment, session_start, session_end = hparams(
            hparam_values, {"eval/team_return": float("nan"), "eval/success_rate": float("nan")}
        )
        file_writer = self.writer._get_file_writer()
        for summary in (experiment, session_start, session_end):
            file_writer.add_summary(summary)
        text = "\n".join(f"    {key}: {value}" for key, value in sorted(flat.items()))
        self.writer.add_text("config", text, 0)

    def scalar(self, tag: str, value: float, step: int) -> None:
        if value is not None and not math.isnan(float(value)):
            self.writer.add_scalar(tag, float(value), step)

    def agent_scalars(self, name: str, values, step: int) -> None:
        """``agent_{i}/{name}`` for each agent; NaNs (no update yet) are skipped."""
        for i, value in enumerate(values):
            self.scalar(f"agent_{i}/{name}", value, step)

    def evaluation_views(self, picture: np.ndarray, q_values: Sequence[np.ndarray], step: int) -> None:
        """An evaluation's picture (``[H, W, 3]`` uint8) and each agent's Q-values (agents with none skipped)."""
        self.writer.add_image("eval/episode", picture, step, dataformats="HWC")
        for i, values in enumerate(q_values):
            if values.size:
                self.writer.add_histogram(f"agent_{i}/q_values", values, step)

    def text(self, tag: str, text: str, step: int = 0) -> None:
        self.writer.add_text(tag, text, step)

    def close(self) -> None:
        self.writer.close()
