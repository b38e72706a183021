"""``dqn-transfer-play``: a trained team's greedy episodes as a GIF and in the terminal; bad input refused."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import always_acting_team, train_env
from PIL import Image

from dqn_transfer.cli.play import main as play
from dqn_transfer.envs import make_game
from dqn_transfer.evaluation.watch import map_picture

CELL = 40  # the GIF's cell size in pixels
BLUE, GREEN = (31, 119, 180), (44, 160, 44)  # agents 0 and 1
GOLD, FREE = (255, 196, 0), (235, 235, 235)  # a full chest; a free cell (and an emptied chest's inside)


@pytest.fixture(scope="module")
def team(tmp_path_factory) -> Path:
    return always_acting_team(tmp_path_factory.mktemp("team") / "run")


def gif_frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as gif:
        frames = []
        for index in range(gif.n_frames):
            gif.seek(index)
            frames.append(np.asarray(gif.convert("RGB")).astype(int))
        return frames


def near(pixel: np.ndarray, colour: tuple[int, int, int]) -> bool:
    return bool(np.abs(pixel - np.asarray(colour)).max() <= 12)  # GIF palettes shift colours a little


def test_gif_has_one_frame_per_step_plus_the_first(team, tmp_path, capsys):
    gif = tmp_path / "team.gif"
    assert play([str(team), "--gif", str(gif)]) == 0
    out = capsys.readouterr().out
    assert "episode 1: 9 steps, team return 90, chests 1/1, trapped agents 0/2" in out
    assert f"wrote {gif} (10 frames)" in out
    frames = gif_frames(gif)
    assert len(frames) == 9 + 1
    assert play([str(team), "--episodes", "3", "--gif", str(gif)]) == 0
    assert len(gif_frames(gif)) == 3 * (9 + 1)


def test_gif_frames_show_agents_chests_and_trails(team, tmp_path):
    gif = tmp_path / "team.gif"
    play([str(team), "--gif", str(gif)])
    first, after_two_steps, last = (gif_frames(gif)[i] for i in (0, 2, -1))
    # Frame 0: agent 0's disc on its start (left of its centre, clear of the white number), agent 1's
    # below it, the chest (top right) full: gold inside its frame.
    assert near(first[CELL // 2, CELL // 2 - 11], BLUE) and near(first[CELL + CELL // 2, CELL // 2 - 11], GREEN)
    assert near(first[8, 2 * CELL + 8], GOLD)
    # After step 2 agent 0 has taken the chest: emptied (its inside, clear of the ring, is free colour).
    assert near(after_two_steps[8, 2 * CELL + 8], FREE)
    # Agent 0's trail runs along the top row: blue where cells (0, 0) and (0, 1) meet, a little above the
    # row's middle (the trails of two agents are drawn apart by an eighth of a cell).
    assert near(last[CELL // 2 - 3, CELL], BLUE)
    assert near(last[CELL + CELL // 2 + 2, CELL], GREEN)  # and agent 1's along the second row


def test_the_map_picture_shows_every_agent_on_its_start_and_every_chest_full():
    picture = np.asarray(map_picture(make_game(layout="0.T\n1..\nX.."))).astype(int)
    assert picture.shape == (3 * CELL, 3 * CELL, 3)  # no caption
    assert near(picture[CELL // 2, CELL // 2 - 11], BLUE) and near(picture[CELL + CELL // 2, CELL // 2 - 11], GREEN)
    assert near(picture[8, 2 * CELL + 8], GOLD)
    assert near(picture[2 * CELL + 4, 4], (200, 30, 30))  # the trap, red


def test_ansi_replays_every_frame_as_text(team, capsys):
    assert play([str(team), "--ansi"]) == 0
    frames = capsys.readouterr().out.split("\n\n")
    assert frames[0].endswith("0.T\n1..\nX..\nstep 0/9  team return 0  full chests 1/1")
    assert frames[2] == "..t\n..1\nX..\nstep 2/9  team return 97  full chests 0/1"  # 0 took the chest; 1 at the edge
    assert frames[9].startswith("..t\n...\nX..\nstep 9/9  team return 90  full chests 0/1")


def test_a_lone_agent_file_drives_every_agent_of_its_map(team, capsys):
    assert play([str(team / "checkpoints" / "agent_1.safetensors")]) == 0
    assert "episode 1: 9 steps, team return 90" in capsys.readouterr().out


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "not_a_run",
        "gif_dir_missing",
        "gif_is_dir",
        "gif_under_file",
        "episodes_zero",
        "episodes_negative",
        "replicas",
        "pickle",
    ],
)
def test_bad_input_is_one_error_line_and_leaves_nothing(case, team, tmp_path, capsys):
    gif = tmp_path / "out.gif"
    args = {
        "missing": [str(tmp_path / "nope")],
        "not_a_run": [str(tmp_path)],
        "gif_dir_missing": [str(team), "--gif", str(tmp_path / "no_dir" / "out.gif")],
        "gif_is_dir": [str(team), "--gif", str(tmp_path)],
        "gif_under_file": [str(team), "--gif", str(team / "metrics.jsonl" / "out.gif")],
        "episodes_zero": [str(team), "--episodes", "0", "--gif", str(gif)],
        "episodes_negative": [str(team), "--episodes", "-2"],
        "replicas": [str(tmp_path / "batch")],
        "pickle": [str(tmp_path / "agent_0.pt")],
    }[case]
    if case == "replicas":
        (tmp_path / "batch").mkdir()
        (tmp_path / "batch" / "replicas.json").write_text('{"replicas": ["seed_0", "seed_1"]}')
    if case == "pickle":
        (tmp_path / "agent_0.pt").write_bytes(b"\x80\x04K\x01.")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert play(args) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    expected = {
        "missing": "no such file or directory",
        "not_a_run": "no agent_*.safetensors",
        "gif_dir_missing": "does not exist",
        "gif_is_dir": "is a directory",
        "gif_under_file": "does not exist",
        "episodes_zero": "--episodes must be >= 1, got 0",
        "episodes_negative": "--episodes must be >= 1, got -2",
        "replicas": "run of 2 replicas",
        "pickle": "refusing to load it",
    }[case]
    assert expected in lines[0]
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    assert not gif.exists()


@pytest.mark.slow
def test_the_console_script_and_the_module_play(team, tmp_path):
    script = shutil.which("dqn-transfer-play", path=str(Path(sys.executable).parent))
    assert script, "the console script is installed with the package (pip install -e .)"
    gif = tmp_path / "team.gif"
    for command in ([script, str(team), "--gif", str(gif)], [sys.executable, "-m", "dqn_transfer.play", str(team)]):
        proc = subprocess.run(command, env=train_env(), capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert "episode 1: 9 steps, team return 90" in proc.stdout
    assert len(gif_frames(gif)) == 10
    proc = subprocess.run(
        [script, str(tmp_path / "nope")], env=train_env(), capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 1 and proc.stderr.startswith("error: ") and "Traceback" not in proc.stderr
