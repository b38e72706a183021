"""TensorBoard at each evaluation: the first episode as a picture, each agent's Q-values as a histogram,
and ``eval/trap_rate``; served by a real TensorBoard on loopback.

The team is the always-right one of conftest, warm-started into a run that never updates (its first
update would come after 1,000 steps), so its greedy evaluation episode is known by hand: agent 0
takes the chest on step 2, agent 1 stands at the right edge until the 9th step truncates it; every
observation's Q-values are ``[0, 0, 0, 1]``.
"""

from __future__ import annotations

import io
import json
import math
import re
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest
from conftest import DOWN, always_acting_team, compose_config
from PIL import Image
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.backend.event_processing.event_file_loader import EventFileLoader
from tensorboard.compat.proto.event_pb2 import Event
from tensorboard.compat.proto.summary_pb2 import Summary
from tensorboard.plugins.custom_scalar import layout_pb2
from tensorboard.plugins.custom_scalar import metadata as custom_scalar_metadata
from tensorboard.plugins.hparams import metadata as hparams_metadata
from tensorboard.plugins.hparams import plugin_data_pb2
from tensorboard.summary.writer.record_writer import RecordWriter

from dqn_transfer.config import AgentConfig, TrainConfig, TransferConfig
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.loggers import RunLoggers
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.tensorboard import EventFile, RunLogger, event_record, png_bytes
from dqn_transfer.training.trainer import train

CELL = 32  # TensorBoard's cell size in pixels
BLUE, GREEN, GOLD, FREE = (31, 119, 180), (44, 160, 44), (255, 196, 0), (235, 235, 235)
SERVER_TIMEOUT = 90  # seconds for TensorBoard to start and load the run


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> RunDir:
    base = tmp_path_factory.mktemp("tb")
    source = always_acting_team(base / "source") / "checkpoints" / "agent_0.safetensors"
    env = EnvConfig(layout="0.T\n1..\nX..", size=3, num_treasures=1, num_traps=1, num_agents=2, complexity=0.0)
    config = TrainConfig(
        env=env,
        agent=AgentConfig(algorithm="dqn", hidden=[8]),
        total_steps=1,
        eval_every=1,
        eval_episodes=1,
        progress=False,
        transfer=TransferConfig(enabled=True, source=str(source)),
    )
    train(plan_run(config), base / "run", sources=[source])
    return RunDir(base / "run")


def events(run: RunDir) -> EventAccumulator:
    accumulator = EventAccumulator(str(run.tensorboard), size_guidance={"images": 0, "histograms": 0, "scalars": 0})
    accumulator.Reload()
    return accumulator


def check_picture(png: bytes) -> None:
    """The evaluation episode's last frame: 3 x 3 cells and a caption below; the chest emptied, each
    agent's trail along its row in its colour."""
    picture = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    assert picture.shape[1] == 3 * CELL and picture.shape[0] > 3 * CELL
    near = lambda pixel, colour: np.abs(pixel - np.asarray(colour)).max() <= 3  # noqa: E731
    assert near(picture[6, 2 * CELL + 6], FREE)  # inside the emptied chest's frame, clear of agent 0's ring
    assert near(picture[CELL // 2 - 2, CELL], BLUE)  # agent 0's trail from cell (0, 0) to (0, 1)
    assert near(picture[CELL + CELL // 2 + 2, CELL], GREEN)  # agent 1's from (1, 0) to (1, 1)


def test_each_evaluation_logs_its_picture_q_values_and_trap_rate(run):
    accumulator = events(run)
    images = accumulator.Images("eval/episode")
    assert [image.step for image in images] == [0, 1]  # the evaluations at step 0 and at the end
    check_picture(images[0].encoded_image_string)
    for agent, observations in ((0, 2), (1, 9)):  # agent 0 acted twice, agent 1 nine times
        histogram = accumulator.Histograms(f"agent_{agent}/q_values")[0].histogram_value
        assert histogram.num == 4 * observations and histogram.sum == observations
        assert (histogram.min, histogram.max) == (0.0, 1.0)
    assert [s.value for s in accumulator.Scalars("eval/trap_rate")] == [0.0, 0.0]


def test_the_trap_rate_is_the_one_in_metrics_jsonl(tmp_path):
    """A lone agent that starts above a trap and always moves down: trapped on step 1."""
    layout = "0.T\nX..\n..."
    file = always_acting_team(tmp_path / "source", DOWN, layout) / "checkpoints" / "agent_0.safetensors"
    env = EnvConfig(layout=layout, size=3, num_treasures=1, num_traps=1, num_agents=1, complexity=0.0)
    config = TrainConfig(
        env=env,
        agent=AgentConfig(algorithm="dqn", hidden=[8]),
        total_steps=1,
        eval_every=1,
        eval_episodes=1,
        progress=False,
        transfer=TransferConfig(enabled=True, source=str(file)),
    )
    train(plan_run(config), tmp_path / "run", sources=[file])
    metrics = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [m["trap_rate"] for m in metrics] == [1.0, 1.0]
    assert [s.value for s in events(RunDir(tmp_path / "run")).Scalars("eval/trap_rate")] == [1.0, 1.0]


def get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as response:
        return response.read()


@pytest.mark.slow
def test_a_tensorboard_server_on_loopback_serves_the_picture(run):
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tensorboard.main",
            "--logdir",
            str(run.tensorboard),
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--load_fast",
            "false",
            "--reload_interval",
            "1",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + SERVER_TIMEOUT
        address = None
        while address is None and time.monotonic() < deadline:
            line = server.stdout.readline()
            if not line and server.poll() is not None:
                pytest.fail("tensorboard exited before serving")
            address = re.search(r"http://127\.0\.0\.1:\d+", line)
        assert address, "tensorboard did not say where it serves"
        base = address.group(0)
        tags: dict = {}
        while "eval/episode" not in tags.get(".", {}) and time.monotonic() < deadline:
            tags = json.loads(get(f"{base}/data/plugin/images/tags"))
            time.sleep(0.5)
        assert "eval/episode" in tags.get(".", {}), tags
        entries = json.loads(get(f"{base}/data/plugin/images/images?run=.&tag=eval%2Fepisode"))
        assert [entry["step"] for entry in entries] == [0, 1]
        png = get(f"{base}/data/plugin/images/individualImage?{entries[0]['query']}")
        assert png == events(run).Images("eval/episode")[0].encoded_image_string
        check_picture(png)
        histograms = json.loads(get(f"{base}/data/plugin/histograms/tags"))["."]
        scalars = json.loads(get(f"{base}/data/plugin/scalars/tags"))["."]
        assert {"agent_0/q_values", "agent_1/q_values"} <= set(histograms) and "eval/trap_rate" in scalars
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def scalar_points(run_dir) -> dict[str, list[tuple[int, float]]]:
    accumulator = events(RunDir(run_dir))
    return {tag: [(s.step, s.value) for s in accumulator.Scalars(tag)] for tag in accumulator.Tags()["scalars"]}


def test_points_written_together_read_back_as_one_event_each_written_at_once(tmp_path, monkeypatch):
    """A step's scalars go out as one event (a summary with a value per tag), and the episodes' ends wait
    in arrays for the log interval, then go out in one batch per replica: TensorBoard reads the same
    tags, steps and values, and the CSV the same rows in the same order, as when every episode was
    logged the moment it ended and each point was an event of its own, as they used to be."""
    env = EnvConfig(size=4, num_treasures=1, num_traps=1, num_agents=2, max_steps=15)
    agent = AgentConfig(algorithm="dqn", hidden=[8], learning_starts=50, batch_size=8)
    config = TrainConfig(
        env=env,
        agent=agent,
        total_steps=400,
        eval_every=200,
        eval_episodes=2,
        progress=False,
        eval_pictures=False,
        logger=["tensorboard", "csv"],
    )
    train(plan_run(config), tmp_path / "together")

    def one_event_each(self, values, step):
        for tag, value in values:
            if value is not None and not math.isnan(float(value)):
                self._add(Summary(value=[Summary.Value(tag=tag, simple_value=float(value))]), step)

    def logged_at_once(self, step, values):
        self.scalars(zip(self.episode_tags, values.tolist()), step)

    monkeypatch.setattr(RunLogger, "scalars", one_event_each)
    monkeypatch.setattr(RunLoggers, "episode", logged_at_once)
    train(plan_run(config), tmp_path / "apart")
    together, apart = scalar_points(tmp_path / "together"), scalar_points(tmp_path / "apart")
    for tag in (
        "agent_1/episodic_return",
        "agent_0/episodic_length",
        "team/return",
        "team/treasures_collected",
        "team/trap_rate",
        "agent_0/td_loss",
        "agent_1/q_mean",
        "train/epsilon",
        "eval/team_return",
        "eval/success_rate",
        "eval/trap_rate",
    ):
        assert together[tag], tag
    assert len(together["team/return"]) > 20  # episodes enough to batch
    assert [step for step, _ in together.pop("train/sps")] == [step for step, _ in apart.pop("train/sps")]
    assert together == apart  # train/sps aside, which measures the clock
    without_speed = [
        [row for row in (tmp_path / name / "scalars.csv").read_text().splitlines() if ",train/sps," not in row]
        for name in ("together", "apart")
    ]
    assert without_speed[0] == without_speed[1]


def test_event_files_are_framed_as_tensorboards_own_writer_frames_them(tmp_path):
    """EventFile computes the records' CRC32C in C; TensorBoard's RecordWriter (a Python loop) is the
    reference, byte for byte, and TensorBoard reads the file back."""
    events = [
        Event(step=s, wall_time=1.5 * s, summary=Summary(value=[Summary.Value(tag="x", simple_value=s)]))
        for s in range(50)
    ]
    events.append(Event(step=7, file_version="brain.Event:2"))  # and an event of another kind
    reference = io.BytesIO()
    writer = RecordWriter(reference)
    for event in events:
        writer.write(event.SerializeToString())
    assert b"".join(event_record(event.SerializeToString()) for event in events) == reference.getvalue()
    file = EventFile(tmp_path / "tb")
    for event in events[:50]:
        file.add_event(event)
    file.close()
    accumulator = EventAccumulator(str(tmp_path / "tb"))
    accumulator.Reload()
    assert [(e.step, e.value) for e in accumulator.Scalars("x")] == [(s, float(s)) for s in range(50)]
    assert EventFile(tmp_path / "tb")._file.name != file._file.name  # a second file never overwrites the first


def layout_and_hparams_metrics(run: RunDir) -> tuple[list[str], list[str]]:
    """The tags of the run's custom-scalars layout (its charts') and of its hparams metrics."""
    layout_tags, metric_tags = [], []
    for path in run.tensorboard.iterdir():
        for event in EventFileLoader(str(path)).Load():
            for value in event.summary.value:
                if value.tag == custom_scalar_metadata.CONFIG_SUMMARY_TAG:
                    layout = layout_pb2.Layout.FromString(value.tensor.string_val[0])
                    charts = [chart for category in layout.category for chart in category.chart]
                    layout_tags += [tag for chart in charts for tag in chart.multiline.tag]
                elif value.tag == hparams_metadata.EXPERIMENT_TAG:
                    plugin_data = plugin_data_pb2.HParamsPluginData.FromString(value.metadata.plugin_data.content)
                    metric_tags += [info.name.tag for info in plugin_data.experiment.metric_infos]
    return layout_tags, metric_tags


@pytest.mark.parametrize(
    ("game", "eval_tags"),
    [
        ((), ["eval/team_return", "eval/success_rate", "eval/trap_rate"]),
        (("env=lbf",), ["eval/team_return", "eval/episode_length"]),
        (("env=mpe_spread",), ["eval/team_return", "eval/episode_length"]),
        (("env=pettingzoo", "env.factory=corridor_env:parallel_env"), ["eval/team_return", "eval/episode_length"]),
    ],
)
def test_the_layout_and_hparams_metrics_are_the_tags_the_game_records(tmp_path, game, eval_tags):
    """The custom-scalars layout charts exactly the agent, team and evaluation tags the run writes (a
    chart of a tag never written stays empty: another game records no chest or trap), and the hparams
    table compares runs by the game's evaluation tags."""
    config = compose_config(
        *game, "agent=dqn", "agent.hidden=[8]", "agent.learning_starts=20", "total_steps=100", "eval_every=50",
        "eval_episodes=1", "progress=false",
    )  # fmt: skip
    train(plan_run(config), tmp_path / "run")
    run = RunDir(tmp_path / "run")
    layout_tags, metric_tags = layout_and_hparams_metrics(run)
    written = {tag for tag in events(run).Tags()["scalars"] if not tag.startswith("train/")}  # charted apart
    assert sorted(layout_tags) == sorted(written)
    assert metric_tags == eval_tags
    assert {tag for tag in written if tag.startswith("eval/")} == set(eval_tags)


@pytest.mark.parametrize("height, width", [(1, 1), (3, 5), (292, 256)])
def test_png_bytes_decode_to_the_picture_pixel_for_pixel(height, width):
    """The evaluation picture's PNG (written without Pillow) is a valid file Pillow reads back exactly."""
    picture = np.random.default_rng(height).integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    picture[: height // 2] = (250, 250, 250)  # a flat band, as drawn pictures are mostly
    decoded = Image.open(io.BytesIO(png_bytes(picture)))
    decoded.load()  # checks every chunk's CRC and the deflate stream
    assert decoded.mode == "RGB" and decoded.size == (width, height)
    assert np.array_equal(np.asarray(decoded), picture)
