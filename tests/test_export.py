"""``dqn-transfer-ckpt export RUN_DIR OUT_DIR``: the team as a folder with a model card, from which a new
run warm-starts with the same Q-values."""

from __future__ import annotations

import dataclasses
import itertools
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from conftest import reference_mlp, run_train

from dqn_transfer.cli.ckpt import main as ckpt
from dqn_transfer.cli.play import main as play
from dqn_transfer.config import AgentConfig, TrainConfig, TransferConfig
from dqn_transfer.envs import generate_layout
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sharing import model_card
from dqn_transfer.sources.resolve import transfer_sources
from dqn_transfer.storage.checkpoint import load_agent_checkpoint
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train

ENV = EnvConfig(size=4, num_treasures=1, num_traps=1, num_agents=2, complexity=0.0, map_seed=0)
EXPORTED = {"README.md", "agent_0.safetensors", "agent_1.safetensors", "map.txt", "replay.gif"}


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A short DQN run that has learned something (its weights are no longer the initial ones)."""
    run_dir = tmp_path_factory.mktemp("export") / "run"
    agent = AgentConfig(algorithm="dqn", hidden=[16], learning_starts=50)
    train(
        plan_run(TrainConfig(env=ENV, agent=agent, total_steps=200, eval_every=100, eval_episodes=2, progress=False)),
        run_dir,
    )
    return run_dir


def front_matter(card: str) -> dict:
    assert card.startswith("---\n")
    return yaml.safe_load(card.split("---\n")[1])


def every_observation() -> torch.Tensor:
    """Each cell of the 4 x 4 grid as `position`, with each belief about the one chest as `treasures`."""
    rows = [np.concatenate([np.eye(16)[cell], [belief]]) for cell, belief in itertools.product(range(16), (0.0, 1.0))]
    return torch.tensor(np.array(rows), dtype=torch.float32)


def q_values(file: Path) -> torch.Tensor:
    with torch.no_grad():
        return reference_mlp(load_agent_checkpoint(file)[0])(every_observation())


@pytest.fixture(scope="module")
def exported(run, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("shared") / "team"
    assert ckpt(["export", str(run), str(out)]) == 0
    return out


def test_the_folder_holds_the_agents_map_gif_and_card(run, exported):
    assert {p.name for p in exported.iterdir()} == EXPORTED
    for i in (0, 1):  # byte for byte the run's files
        assert (exported / f"agent_{i}.safetensors").read_bytes() == (
            run / "checkpoints" / f"agent_{i}.safetensors"
        ).read_bytes()
    assert (exported / "map.txt").read_text() == generate_layout(
        4, num_treasures=1, num_traps=1, num_agents=2, complexity=0.0, seed=0
    ) + "\n"
    meta = front_matter((exported / "README.md").read_text())
    assert meta["library_name"] == "dqn-transfer"
    assert {"reinforcement-learning", "multi-agent", "dqn"} <= set(meta["tags"])
    assert meta["mode"] == "competitive" and meta["env"]["size"] == 4 and meta["env"]["num_treasures"] == 1
    assert meta["training"]["steps"] == 200 and meta["training"]["seed"] == 0
    assert meta["evaluation"]["episode_seeds"] == [[0, i] for i in range(10)]
    metric = meta["model-index"][0]["results"][0]["metrics"][0]
    assert metric["type"] == "mean_reward"


def test_the_card_metrics_are_what_play_measures_with_the_stated_seeds(exported, capsys):
    evaluation = front_matter((exported / "README.md").read_text())["evaluation"]
    capsys.readouterr()
    assert play([str(exported), "--episodes", "10", "--seed", "0"]) == 0
    returns = [float(x) for x in re.findall(r"team return (-?[\d.]+),", capsys.readouterr().out)]
    assert len(returns) == 10
    assert evaluation["team_return_mean"] == pytest.approx(np.mean(returns), abs=1e-3)
    assert evaluation["team_return_std"] == pytest.approx(np.std(returns), abs=1e-3)


def warm_start(exported: Path, run_dir: Path, env: EnvConfig = ENV, **transfer) -> Path:
    """A run of no steps of its own warm-started from ``exported``; returns its checkpoints."""
    config = TrainConfig(
        env=env,
        agent=AgentConfig(algorithm="dqn", hidden=[16]),
        total_steps=0,
        progress=False,
        transfer=TransferConfig(enabled=True, source=str(exported), **transfer),
    )
    train(plan_run(config), run_dir, sources=transfer_sources(plan_run(config), run_dir.parent))
    return run_dir / "checkpoints"


def test_a_new_team_of_the_same_size_starts_agent_for_agent_from_the_folder(exported, tmp_path):
    warm = warm_start(exported, tmp_path / "warm")
    for i in (0, 1):
        assert torch.equal(q_values(warm / f"agent_{i}.safetensors"), q_values(exported / f"agent_{i}.safetensors"))
    assert not torch.equal(q_values(exported / "agent_1.safetensors"), q_values(exported / "agent_0.safetensors"))
    # transfer.targets: the targets still start from the source agent of their own index.
    only = warm_start(exported, tmp_path / "only_1", targets=[1])
    assert torch.equal(q_values(only / "agent_1.safetensors"), q_values(exported / "agent_1.safetensors"))


def test_source_agent_or_another_team_size_starts_every_agent_from_one(exported, tmp_path):
    pinned = warm_start(exported, tmp_path / "pinned", source_agent=0)
    lone = warm_start(exported, tmp_path / "lone", env=dataclasses.replace(ENV, num_agents=1))
    source = q_values(exported / "agent_0.safetensors")
    assert torch.equal(q_values(pinned / "agent_0.safetensors"), source)
    assert torch.equal(q_values(pinned / "agent_1.safetensors"), source)
    assert [file.name for file in lone.glob("agent_*")] == ["agent_0.safetensors"]
    assert torch.equal(q_values(lone / "agent_0.safetensors"), source)


def test_an_empty_existing_folder_is_fine(run, tmp_path):
    (tmp_path / "empty").mkdir()
    assert ckpt(["export", str(run), str(tmp_path / "empty")]) == 0
    assert {p.name for p in (tmp_path / "empty").iterdir()} == EXPORTED


def test_the_folders_missing_parents_are_made(run, tmp_path):
    """``export RUN shared/team`` in a folder without ``shared/`` (the README's example, issue #31)."""
    assert ckpt(["export", str(run), str(tmp_path / "shared" / "team")]) == 0
    assert {p.name for p in (tmp_path / "shared" / "team").iterdir()} == EXPORTED
    assert [p.name for p in (tmp_path / "shared").iterdir()] == ["team"]


@pytest.mark.parametrize("out", ["team", "shared/deeper/team"])
def test_a_failed_write_leaves_nothing(run, tmp_path, monkeypatch, capsys, out):
    """Nothing of a failed export stays: neither its folder nor the parent folders it made for it."""

    def refuse(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(model_card.os, "rename", refuse)
    assert ckpt(["export", str(run), str(tmp_path / out)]) == 1
    assert capsys.readouterr().err == f"error: cannot export into {tmp_path / out}: No space left on device\n"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "case",
    ["missing_run", "not_a_run", "non_empty_out", "out_is_file", "out_under_a_file", "no_out", "out_with_list"],
)
def test_bad_input_is_one_error_line_and_leaves_nothing(case, run, tmp_path, capsys):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    (tmp_path / "file").write_text("x")
    (tmp_path / "empty_dir").mkdir()
    args, expected = {
        "missing_run": (["export", str(tmp_path / "nope"), str(tmp_path / "out")], "no such file or directory"),
        "not_a_run": (["export", str(tmp_path / "empty_dir"), str(tmp_path / "out")], "no agent_*.safetensors"),
        "non_empty_out": (["export", str(run), str(tmp_path / "full")], "is not empty"),
        "out_is_file": (["export", str(run), str(tmp_path / "file")], "is a file"),
        "out_under_a_file": (["export", str(run), str(tmp_path / "file" / "a" / "b")], "file is a file"),
        "no_out": (["export", str(run)], "OUT_DIR goes with export only"),
        "out_with_list": (["list", str(run), str(tmp_path / "out")], "OUT_DIR goes with export only"),
    }[case]
    before = {p: p.read_bytes() if p.is_file() else None for p in tmp_path.rglob("*")}
    assert ckpt(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and expected in err, err
    assert {p: p.read_bytes() if p.is_file() else None for p in tmp_path.rglob("*")} == before


@pytest.mark.slow
def test_export_then_the_cards_own_command_warm_starts(run, tmp_path):
    """From the command line, as a user would: export, then paste the card's warm-start command."""
    out = tmp_path / "team"
    proc = subprocess.run(
        [sys.executable, "-m", "dqn_transfer.cli.ckpt", "export", str(run), str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    card = (out / "README.md").read_text()
    command = next(line for line in card.splitlines() if line.startswith("python train.py "))
    overrides = shlex.split(command.replace("$FOLDER", str(out)))[2:]
    assert "env.layout_file=" + str(out / "map.txt") in overrides
    run_train(tmp_path, *overrides, "total_steps=0", run_dir=tmp_path / "warm")
    assert torch.equal(
        q_values(tmp_path / "warm" / "checkpoints" / "agent_0.safetensors"), q_values(out / "agent_0.safetensors")
    )


def test_the_cards_command_names_every_rule_that_differs_from_the_default(tmp_path):
    env = EnvConfig(
        size=4, num_treasures=1, num_traps=1, num_agents=2, complexity=0.0, view_radius=1, reward_mode="team"
    )
    train(
        plan_run(
            TrainConfig(
                env=env, agent=AgentConfig(algorithm="double_dqn", hidden=[8, 8]), total_steps=0, progress=False
            )
        ),
        tmp_path / "run",
    )
    assert ckpt(["export", str(tmp_path / "run"), str(tmp_path / "team")]) == 0
    command = next(
        line
        for line in (tmp_path / "team" / "README.md").read_text().splitlines()
        if line.startswith("python train.py ")
    )
    assert shlex.split(command)[2:] == [
        "agent=double_dqn",
        "mode=competitive",
        "transfer=on",
        "transfer.source=$FOLDER",
        "env.layout_file=$FOLDER/map.txt",
        "env.reward_mode=team",
        "env.view_radius=1",
        "agent.hidden=[8,8]",
    ]


def test_the_card_says_where_a_warm_started_teams_agents_started(run, exported, tmp_path):
    """A team that was itself warm-started (here from ``run``) says so, with its source and steps; a
    team trained from scratch says that."""
    scratch = (exported / "README.md").read_text()
    assert front_matter(scratch)["warm_started_from"] is None and "From scratch" in scratch
    agent = AgentConfig(algorithm="dqn", hidden=[16], learning_starts=50)
    config = TrainConfig(
        env=ENV,
        agent=agent,
        total_steps=0,
        progress=False,
        transfer=TransferConfig(enabled=True, source=str(run)),
    )
    plan = plan_run(config)
    train(plan, tmp_path / "warm", sources=transfer_sources(plan, tmp_path))
    out = tmp_path / "team"
    assert ckpt(["export", str(tmp_path / "warm"), str(out)]) == 0
    card = (out / "README.md").read_text()
    [start] = front_matter(card)["warm_started_from"]
    assert start["source"] == str((run / "checkpoints" / "agent_0.safetensors").resolve())
    assert start["source_steps"] == 200 and start["pretrained_source"] is False
    section = card[card.index("## Where its agents started") :]
    assert f"1. `{start['source']}` (200 steps" in section and "From scratch" not in card
