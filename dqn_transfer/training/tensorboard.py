"""TensorBoard logging with the tag names other tools rely on.

Per agent: ``agent_{i}/episodic_return``, ``agent_{i}/episodic_length``, ``agent_{i}/td_loss``,
``agent_{i}/q_mean``, and the histogram ``agent_{i}/q_values`` (at each evaluation: the Q-values of
every observation the agent acted on in the evaluation's first episode).  Team: ``team/return`` and
the game's ``episode_metrics`` (the treasure hunt's ``team/treasures_collected``, ``team/trap_rate``).
Evaluation: ``eval/`` and each of the game's ``headline_metrics`` (the treasure hunt's
``eval/team_return``, ``eval/success_rate``, ``eval/trap_rate``; another game's ``eval/team_return``,
``eval/episode_length``), and the image ``eval/episode`` (the treasure hunt's first episode's last
frame with every agent's trail).  Training: ``train/epsilon``, ``train/sps``.
A custom-scalars layout overlays the agents' curves in one chart each and charts the team's and the
evaluations' tags the game records; the flattened config goes to the hparams plugin (so runs of a
sweep can be compared in its table, by the game's evaluation tags) and, as YAML, to the text plugin.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import socket
import struct
import time
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import google_crc32c
import numpy as np

# TensorBoard's own summary builders and event writer: no torch (or TensorFlow) needed to write logs.
from tensorboard.compat.proto.event_pb2 import Event, SessionLog
from tensorboard.compat.proto.summary_pb2 import HistogramProto, Summary, SummaryMetadata
from tensorboard.compat.proto.tensor_pb2 import TensorProto
from tensorboard.plugins.custom_scalar import layout_pb2
from tensorboard.plugins.custom_scalar import metadata as custom_scalar_metadata
from tensorboard.plugins.hparams import summary_v2 as hparams_summary
from tensorboard.plugins.text import summary_v2 as text_summary

from dqn_transfer.storage.run_dir import flatten

AGENT_TAGS = ("episodic_return", "episodic_length", "td_loss", "q_mean")


def episode_tags(num_agents: int, team_metrics: Sequence[str]) -> list[str]:
    """The tags of a training episode's end, in the order of its row of values: each agent's
    ``episodic_return``, each agent's ``episodic_length``, ``team/return``, then ``team/{key}`` of each
    of the game's ``episode_metrics``."""
    agents = range(num_agents)
    return [
        *(f"agent_{i}/episodic_return" for i in agents),
        *(f"agent_{i}/episodic_length" for i in agents),
        "team/return",
        *(f"team/{key}" for key in team_metrics),
    ]


def json_list(value: Any) -> Any:
    """A config value as an hparam: a list or tuple becomes a JSON string."""
    return json.dumps(list(value)) if isinstance(value, (list, tuple)) else value


def histogram(values: np.ndarray, bins: int = 30) -> HistogramProto:
    """TensorBoard's histogram of ``values``: ``bucket[i]`` values up to ``bucket_limit[i]``."""
    values = np.asarray(values, dtype=np.float64).ravel()
    counts, edges = np.histogram(values, bins=bins)
    return HistogramProto(
        min=values.min(),
        max=values.max(),
        num=values.size,
        sum=values.sum(),
        sum_squares=float(values @ values),
        bucket_limit=edges[1:].tolist(),
        bucket=counts.tolist(),
    )


def png_bytes(picture: np.ndarray) -> bytes:
    """``picture [H, W, 3]`` uint8 as a PNG file: its rows unfiltered, deflated at level 1.

    Pillow chooses a filter for every row, which flat-coloured pictures do not need: for TensorBoard's
    evaluation picture (256 x 292), written at every evaluation, this takes 0.31 ms and Pillow 1.1 ms
    (``compress_level=1``) for a file 12% larger.
    """
    height, width, _ = picture.shape
    rows = np.zeros((height, 1 + width * 3), dtype=np.uint8)  # each row: its filter type (0, none), its pixels
    rows[:, 1:] = picture.reshape(height, -1)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, deflate, no interlace
    idat = zlib.compress(rows.tobytes(), 1)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def masked_crc32c(data: bytes) -> int:
    """TFRecord's masked CRC32C of ``data`` (rotated right by 15 bits, plus a constant)."""
    crc = google_crc32c.value(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def event_record(data: bytes) -> bytes:
    """One TFRecord: length (uint64), its masked CRC, the data, the data's masked CRC (little-endian)."""
    header = struct.pack("<Q", len(data))
    return header + struct.pack("<I", masked_crc32c(header)) + data + struct.pack("<I", masked_crc32c(data))


_EVENT_FILES = itertools.count()


class EventFile:
    """A TensorBoard event file, as TensorBoard's ``EventFileWriter`` writes it (the same name, first
    event and records), written from the calling thread with the CRCs computed in C.

    ``EventFileWriter`` computes each record's CRC32C in a Python loop over its bytes (~60 us for an
    episode end's event) on a writer thread that every event wakes (one per replica). Here the records
    go into the file's buffer, which goes to the operating system when it fills and at each
    :meth:`flush` (the run's log interval, its checkpoints, its end), and reaches the disk at a
    durable flush (checkpoints, the end). Still one event per episode once they are batched: swapped for
    TensorBoard's or tensorboardX's writer, a 100-replica SARSA run took 1.56x or 1.77x the CPU time
    (docs/integrations.md).
    """

    def __init__(self, logdir: Path) -> None:
        logdir.mkdir(parents=True, exist_ok=True)
        number = next(_EVENT_FILES)  # two files of one process in one second never share a name
        name = f"events.out.tfevents.{time.time():010.0f}.{socket.gethostname()}.{os.getpid()}.{number}"
        self._file = open(logdir / name, "xb")  # noqa: SIM115 (closed by close())
        first = Event(wall_time=time.time(), file_version="brain.Event:2")
        first.source_metadata.writer = "tensorboard.summary.writer.event_file_writer"
        self.add_event(first)
        self.flush()

    def add_event(self, event: Event) -> None:
        self._file.write(event_record(event.SerializeToString()))

    def flush(self, durable: bool = False) -> None:
        """Hand the buffered records to the operating system (a killed process keeps them), and with
        ``durable`` wait until they are on the disk (a crashed machine keeps them)."""
        self._file.flush()
        if durable:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


class RunLogger:
    """Writes a run's TensorBoard events and owns the tag vocabulary.

    :param tb_dir: the directory of the run's event files.
    :param num_agents: the team's size.
    :param config: the run's config, as plain data (for the hparams and text plugins).
    :param eval_metrics: the keys each evaluation logs as ``eval/{key}`` (the game's ``headline_metrics``).
    :param team_metrics: the keys each training episode's end logs as ``team/{key}`` besides
        ``team/return`` (the game's ``episode_metrics``).
    :param purge_step: a resumed run's first step: events of the killed run from this step on are
        hidden by TensorBoard, which the run then logs again.
    """

    def __init__(
        self,
        tb_dir: Path,
        num_agents: int,
        config: Mapping[str, Any],
        eval_metrics: Sequence[str],
        team_metrics: Sequence[str],
        purge_step: int | None = None,
    ):
        self.writer = EventFile(Path(tb_dir))
        self.num_agents = num_agents
        self.eval_tags = [f"eval/{key}" for key in eval_metrics]
        self.team_tags = [f"team/{key}" for key in team_metrics]
        if purge_step:  # TensorBoard drops the earlier events at or after the step of a restart
            self.writer.add_event(
                Event(step=purge_step, wall_time=time.time(), session_log=SessionLog(status=SessionLog.START))
            )
        else:  # a resumed run already has its layout, hparams and text
            self._write_layout()
            self._write_config(config)

    def _add(self, summary: Summary, step: int = 0) -> None:
        self.writer.add_event(Event(summary=summary, step=step, wall_time=time.time()))

    def flush(self, durable: bool = False) -> None:
        self.writer.flush(durable)

    def _write_layout(self) -> None:
        agents = range(self.num_agents)
        per_agent = {tag: [f"agent_{i}/{tag}" for i in agents] for tag in AGENT_TAGS}
        eval_return = [tag for tag in self.eval_tags if tag == "eval/team_return"]
        eval_others = [tag for tag in self.eval_tags if tag != "eval/team_return"]
        # A chart for each group the game records: a chart of tags never written would stay empty.
        team = {"return": ["team/return", *eval_return]}
        team.update({" and ".join(tags): tags for tags in (self.team_tags, eval_others) if tags})
        layout = layout_pb2.Layout(
            category=[
                layout_pb2.Category(
                    title=title,
                    chart=[
                        layout_pb2.Chart(title=name, multiline=layout_pb2.MultilineChartContent(tag=tags))
                        for name, tags in charts.items()
                    ],
                )
                for title, charts in (("agents", per_agent), ("team", team))
            ]
        )
        # What tensorboard.plugins.custom_scalar.summary.pb writes, without its TensorFlow import.
        tensor = TensorProto(dtype="DT_STRING", string_val=[layout.SerializeToString()])
        metadata = SummaryMetadata.FromString(custom_scalar_metadata.create_summary_metadata().SerializeToString())
        self._add(
            Summary(
                value=[Summary.Value(tag=custom_scalar_metadata.CONFIG_SUMMARY_TAG, tensor=tensor, metadata=metadata)]
            )
        )

    def _write_config(self, config: Mapping[str, Any]) -> None:
        flat = flatten(config, json_list)
        hparam_values = {key: value for key, value in flat.items() if isinstance(value, (int, float, str, bool))}
        hparam_values.update({key: "null" for key, value in flat.items() if value is None})
        metrics = [hparams_summary.Metric(tag) for tag in self.eval_tags]
        self._add(hparams_summary.hparams_config_pb([hparams_summary.HParam(key) for key in hparam_values], metrics))
        self._add(hparams_summary.hparams_pb(hparam_values))
        text = "\n".join(f"    {key}: {value}" for key, value in sorted(flat.items()))
        self.text("config", text)

    def scalars(self, values: Iterable[tuple[str, float | None]], step: int) -> None:
        """Several ``(tag, value)`` points of one step as one event: a summary with a value per tag,
        which TensorBoard reads as the same points one event each would give, at a fraction of the
        cost (an event is built, queued, framed and checksummed once). NaNs and Nones (no update
        yet) are skipped; nothing is written if none is left."""
        points = [
            Summary.Value(tag=tag, simple_value=float(value))
            for tag, value in values
            if value is not None and not math.isnan(float(value))
        ]
        if points:
            self._add(Summary(value=points), step)

    def scalar_rows(self, tags: Sequence[str], steps: np.ndarray, values: np.ndarray, wall_times: np.ndarray) -> None:
        """Rows of points of ``tags`` (every value a number): row i at ``steps[i]``, logged at
        ``wall_times[i]``, one event as :meth:`scalars` writes a step's points. The rows share one
        event whose values are set row by row: a third of the cost of building an event each."""
        event = Event(summary=Summary(value=[Summary.Value(tag=tag) for tag in tags]))
        fields = event.summary.value
        for step, wall_time, row in zip(steps.tolist(), wall_times.tolist(), values.tolist()):
            event.step, event.wall_time = step, wall_time
            for field, value in zip(fields, row):
                field.simple_value = value
            self.writer.add_event(event)

    @staticmethod
    def agent_values(name: str, values: Iterable[float]) -> list[tuple[str, float]]:
        """``(agent_{i}/{name}, value)`` for each agent, for :meth:`scalars`."""
        return [(f"agent_{i}/{name}", value) for i, value in enumerate(values)]

    def evaluation_views(self, picture: np.ndarray, q_values: Sequence[np.ndarray], step: int) -> None:
        """An evaluation's picture (``[H, W, 3]`` uint8) and each agent's Q-values (agents with none skipped)."""
        height, width, channels = picture.shape
        image = Summary.Image(height=height, width=width, colorspace=channels, encoded_image_string=png_bytes(picture))
        self._add(Summary(value=[Summary.Value(tag="eval/episode", image=image)]), step)
        for i, values in enumerate(q_values):
            if values.size:
                self._add(Summary(value=[Summary.Value(tag=f"agent_{i}/q_values", histo=histogram(values))]), step)

    def text(self, tag: str, text: str, step: int = 0) -> None:
        self._add(text_summary.text_pb(tag, text), step)

    def close(self) -> None:
        self.writer.close()
