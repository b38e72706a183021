"""Where a pretrained source comes from (docs/transfer.md, "Where the source comes from"):
``transfer.source_task`` (``single``: TreasureHunt-v0, the default; ``team``: the run's own multi-agent
game, the targets starting from its member ``transfer.source_agent``) and ``transfer.source_map_shift``
(pretrain on the generated map ``env.map_seed + shift``).

What is checked is what a user sees: the cache directory's entries and their names (the hash), the
agent files of an entry read with ``safetensors`` alone, the map each records (compared with the map
generator's own output for that seed), the ``transfer_source`` a run records, and the one-line
refusals of the command line (the only subprocesses, side by side, marked ``slow``). Sources are
pretrained for 200 steps: Q-learning, or a numpy DQN where weights are compared.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    WARM_START_NUMPY_DQN,
    WARM_START_PRETRAIN_STEPS,
    WARM_START_QLEARNING,
    agent_meta,
    read_metrics,
    run_many,
    warm_start_config,
)
from safetensors.numpy import load_file

import dqn_transfer.sources.resolve
from dqn_transfer.config import (
    AgentConfig,
    ConfigError,
    CurriculumConfig,
    ReplicasConfig,
    StageConfig,
    TrainConfig,
    to_plain,
    validate,
)
from dqn_transfer.enums import Mode, RewardMode, SourceTask
from dqn_transfer.envs.maps import generate_layout
from dqn_transfer.envs.settings import ENV_KEYS, EnvConfig
from dqn_transfer.sources.resolve import source_hash, transfer_sources
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train
from dqn_transfer.transfer.mapping import TransferError

# Two agents, two chests (row 0 col 4, row 4 col 4), one trap (row 2 col 2), no obstacles.
MAP = "0...T\n.....\n..X..\n.....\n1...T\n"
PLAYED = MAP.rstrip("\n")  # the map as a run records it (no final newline)
PRETRAIN_STEPS = WARM_START_PRETRAIN_STEPS
SHIFT = 1000
# A generated map: 5x5, 2 chests, 1 trap, 2 agents, no obstacles, map seed 3 (the shifted source: 1003).
GENERATED = dict(size=5, num_treasures=2, num_traps=1, num_agents=2, complexity=0.0)
MAP_SEED = 3
PRETRAINING = "transfer: pretraining"
QLEARNING, NUMPY_DQN = WARM_START_QLEARNING, WARM_START_NUMPY_DQN


def config(cache: Path, *, agent: AgentConfig = QLEARNING, env: EnvConfig | None = None, **transfer) -> TrainConfig:
    return warm_start_config(cache, MAP, 1, agent, env, **transfer)


def generated(map_seed: int = MAP_SEED, **env) -> EnvConfig:
    return EnvConfig(**GENERATED, map_seed=map_seed, **env)


def generated_layout(map_seed: int) -> str:
    """The map generator's own output for a map seed: what the env config of that seed plays on."""
    return generate_layout(
        GENERATED["size"],
        GENERATED["num_treasures"],
        GENERATED["num_traps"],
        GENERATED["num_agents"],
        GENERATED["complexity"],
        seed=map_seed,
    )


def entries(cache: Path) -> list[str]:
    return sorted(p.name for p in cache.iterdir() if p.is_dir() and not p.name.startswith("."))


def agent_files(entry: Path) -> list[str]:
    return sorted(p.name for p in (entry / "checkpoints").glob("agent_*.safetensors"))


@pytest.fixture
def pretrainings(monkeypatch) -> list[TrainConfig]:
    """Every pretraining run started from now on (its config), each still carried out."""
    real, runs = dqn_transfer.sources.resolve.train_on_cores, []

    def counted(plan, *args, **kwargs):
        runs.append(plan.config)
        return real(plan, *args, **kwargs)

    monkeypatch.setattr(dqn_transfer.sources.resolve, "train_on_cores", counted)
    return runs


# ------------------------------------------------------------------------- single (the default)


def old_source_hash(config: TrainConfig, layout: str) -> str:
    """The cache key as it was before source_task / source_map_shift existed, written out here: the env
    keys but mode, reward_mode and render_mode (the layout as text, no file; contention, which came later,
    chooses the layout), the agent block, the seed and the pretraining steps."""
    plain = to_plain(config)
    left_out = ("mode", "reward_mode", "render_mode", "contention")
    env = {key: plain["env"][key] for key in ENV_KEYS if key not in left_out}
    env.update(layout_file=None, layout=layout)
    key = {
        "env": env,
        "agent": plain["agent"],
        "seed": plain["seed"],
        "pretrain_steps": plain["transfer"]["pretrain_steps"],
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def test_the_default_source_keeps_its_cache_key_and_its_task(tmp_path, pretrainings):
    """An unchanged config pretrains into the very entry earlier versions made (so existing caches
    stay valid): TreasureHunt-v0, one agent file, the same key for every mode."""
    cache = tmp_path / "cache"
    lone = config(cache)
    assert lone.transfer.source_task is SourceTask.single and lone.transfer.source_map_shift == 0
    [[first, second]] = transfer_sources(plan_run(lone), tmp_path)
    assert entries(cache) == [old_source_hash(lone, PLAYED)]
    assert source_hash(to_plain(lone), PLAYED) == old_source_hash(lone, PLAYED)  # called the old way
    assert first == second == cache / old_source_hash(lone, PLAYED) / "checkpoints" / "agent_0.safetensors"
    assert agent_files(first.parent.parent) == ["agent_0.safetensors"]
    meta = agent_meta(first)
    assert meta["source_task"] is True and meta["steps"] == PRETRAIN_STEPS
    assert len(pretrainings) == 1
    # A generated map too (its layout enters the key, as before).
    on_generated = config(cache, env=generated())
    transfer_sources(plan_run(on_generated), tmp_path)
    assert old_source_hash(on_generated, generated_layout(MAP_SEED)) in entries(cache)


def test_mode_and_reward_mode_enter_the_key_of_a_team_source_only(tmp_path, pretrainings):
    cache = tmp_path / "cache"

    def with_env(task: SourceTask, **env) -> TrainConfig:
        base = config(cache, source_task=task)
        return dataclasses.replace(base, env=dataclasses.replace(base.env, **env))

    for env in ({}, {"mode": Mode.cooperative}, {"reward_mode": RewardMode.team}):
        transfer_sources(plan_run(with_env(SourceTask.single, **env)), tmp_path)
    assert len(pretrainings) == 1 and len(entries(cache)) == 1  # a lone agent's task has no mode
    for env in ({}, {"mode": Mode.cooperative}, {"reward_mode": RewardMode.team}):
        transfer_sources(plan_run(with_env(SourceTask.team, **env)), tmp_path)
    assert len(pretrainings) == 4 and len(entries(cache)) == 4
    assert [(run.env.mode, run.env.reward_mode) for run in pretrainings[1:]] == [
        (Mode.competitive, RewardMode.individual),
        (Mode.cooperative, RewardMode.individual),
        (Mode.competitive, RewardMode.team),
    ]  # each team source played its run's own game
    transfer_sources(plan_run(with_env(SourceTask.team, mode=Mode.cooperative)), tmp_path)
    assert len(pretrainings) == 4  # reused


# ------------------------------------------------------------------------- team


def test_targets_start_from_the_chosen_member_of_a_pretrained_team(tmp_path, pretrainings, caplog):
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    cache = tmp_path / "cache"
    team = config(cache, agent=NUMPY_DQN, source_task=SourceTask.team, source_agent=1)
    [[first, second]] = transfer_sources(plan_run(team), tmp_path)
    entry = first.parent.parent
    assert entries(cache) == [entry.name] and first == second == entry / "checkpoints" / "agent_1.safetensors"
    # The entry is a run of the team game: both members, pretrained for pretrain_steps joint steps.
    assert agent_files(entry) == ["agent_0.safetensors", "agent_1.safetensors"]
    for index, name in enumerate(agent_files(entry)):
        meta = agent_meta(entry / "checkpoints" / name)
        assert (meta["agent_index"], meta["steps"], meta["source_task"], meta["transfer"]) == (
            index,
            PRETRAIN_STEPS,
            False,
            None,
        )
        assert meta["env"]["layout"] == PLAYED and meta["env"]["num_agents"] == 2
        assert [segment for segment, _ in meta["obs_layout"]][:2] == ["position", "treasures"]
    assert len(pretrainings) == 1 and pretrainings[0].total_steps == PRETRAIN_STEPS
    assert "pretraining a source team" in caplog.text
    members = [load_file(str(entry / "checkpoints" / name)) for name in agent_files(entry)]
    assert not np.array_equal(members[0]["q.layers.0.weight"], members[1]["q.layers.0.weight"])

    train(plan_run(team), tmp_path / "run", sources=[[first, second]])  # total_steps=0: the agents as transferred
    for i in range(2):
        target = load_file(str(tmp_path / "run" / "checkpoints" / f"agent_{i}.safetensors"))
        for name in ("q.layers.0.weight", "q.layers.0.bias", "q.layers.1.weight", "q.layers.1.bias"):
            assert np.array_equal(target[name], members[1][name]), (i, name)
    record = agent_meta(tmp_path / "run" / "checkpoints" / "agent_0.safetensors")["transfer"]
    assert record["source"] == str(first.resolve()) and record["source_agent"] == 1
    assert record["source_steps"] == PRETRAIN_STEPS  # what analysis.runs.steps_before adds up

    # Another choice of members reuses the cached team: no pretraining again.
    caplog.clear()
    other = dataclasses.replace(team, transfer=dataclasses.replace(team.transfer, source_agent=[1, 0]))
    assert transfer_sources(plan_run(other), tmp_path) == [
        [entry / "checkpoints" / "agent_1.safetensors", entry / "checkpoints" / "agent_0.safetensors"]
    ]
    assert len(pretrainings) == 1 and "reusing the pretrained source" in caplog.text
    train(plan_run(other), tmp_path / "run2", sources=transfer_sources(plan_run(other), tmp_path))
    for i, member in enumerate((1, 0)):
        target = load_file(str(tmp_path / "run2" / "checkpoints" / f"agent_{i}.safetensors"))
        assert np.array_equal(target["q.layers.0.weight"], members[member]["q.layers.0.weight"])


def test_team_sources_of_replicas_are_pretrained_as_one_batch(tmp_path, pretrainings):
    cache = tmp_path / "cache"
    batch = dataclasses.replace(config(cache, source_task=SourceTask.team), replicas=ReplicasConfig(seeds=2))
    per_replica = transfer_sources(plan_run(batch), tmp_path)
    assert [run.replicas.seeds for run in pretrainings] == [2]
    sources = [targets[0] for targets in per_replica]
    assert len(set(sources)) == 2 and sorted(entries(cache)) == sorted(p.parent.parent.name for p in sources)
    for seed, source in enumerate(sources):
        assert agent_files(source.parent.parent) == ["agent_0.safetensors", "agent_1.safetensors"]
        lone = dataclasses.replace(config(tmp_path / "lone", source_task=SourceTask.team), seed=seed)
        [[alone, _]] = transfer_sources(plan_run(lone), tmp_path)
        assert alone.parent.parent.name == source.parent.parent.name  # the same key
        assert agent_meta(alone)["digest"] == agent_meta(source)["digest"]  # the same training


# ------------------------------------------------------------------------- source_map_shift


@pytest.mark.parametrize("task", [SourceTask.single, SourceTask.team])
def test_a_shifted_source_learns_the_map_of_the_shifted_seed(tmp_path, pretrainings, task):
    cache = tmp_path / "cache"
    run = config(cache, env=generated(), source_task=task, source_map_shift=SHIFT)
    [[first, _]] = transfer_sources(plan_run(run), tmp_path)
    own, shifted = generated_layout(MAP_SEED), generated_layout(MAP_SEED + SHIFT)
    assert own != shifted
    meta = agent_meta(first)
    assert meta["env"]["layout"] == shifted and meta["source_task"] is (task is SourceTask.single)
    assert [run.env.map_seed for run in pretrainings] == [MAP_SEED + SHIFT]
    # The run itself plays its own map, warm-started from the other one: source chests on cells
    # where this map has none are dropped (and recorded), matched ones kept.
    train(plan_run(dataclasses.replace(run, total_steps=10, eval_every=10)), tmp_path / "run", sources=[[first, first]])
    record = read_metrics(tmp_path / "run")[0]["transfer_source"]
    chests = {
        layout: {(r, c) for r, row in enumerate(layout.splitlines()) for c, ch in enumerate(row) if ch == "T"}
        for layout in (own, shifted)
    }
    assert chests[shifted] & chests[own] and chests[shifted] - chests[own]  # the maps share one chest cell of two
    assert sorted(map(tuple, record["mapping"]["dropped_chests"])) == sorted(chests[shifted] - chests[own])
    assert record["source_steps"] == PRETRAIN_STEPS


def test_each_replica_shifts_its_own_map_seed(tmp_path, pretrainings):
    """Two map replicas (seeds 3 and 4): their sources learn maps 1003 and 1004, pretrained as one batch;
    each is the very source a run on that map (no shift) pretrains, so that run reuses it."""
    cache = tmp_path / "cache"
    batch = dataclasses.replace(config(cache, env=generated(), source_map_shift=SHIFT), replicas=ReplicasConfig(maps=2))
    sources = [targets[0] for targets in transfer_sources(plan_run(batch), tmp_path)]
    assert [agent_meta(source)["env"]["layout"] for source in sources] == [
        generated_layout(MAP_SEED + SHIFT),
        generated_layout(MAP_SEED + 1 + SHIFT),
    ]
    assert len(pretrainings) == 1 and len(entries(cache)) == 2
    on_that_map = config(cache, env=generated(map_seed=MAP_SEED + 1 + SHIFT))
    assert transfer_sources(plan_run(on_that_map), tmp_path)[0][0] == sources[1]
    assert len(pretrainings) == 1


# ------------------------------------------------------------------------- refusals


def test_a_curriculum_refuses_the_pretraining_keys(tmp_path):
    stages = CurriculumConfig(stages=[StageConfig(env={"size": 4}, steps=10)])
    for transfer in ({"source_task": SourceTask.team}, {"source_map_shift": 5}):
        run = dataclasses.replace(config(tmp_path, env=generated(), **transfer), curriculum=stages)
        with pytest.raises(
            ConfigError, match="^curriculum: this run starts from its last stage, not from a pretrained source"
        ):
            validate(run)


def test_a_team_member_the_team_lacks_is_refused_before_pretraining(tmp_path, pretrainings):
    for wanted, message in [
        (
            2,
            r"transfer.source_agent=2: the source team .* of 2 agents \(0..1\), which has no "
            r"agent 2$",
        ),
        ([0, 1, 0], r"transfer.source_agent lists 3 source agents for 2 target agents"),
    ]:
        with pytest.raises(TransferError, match=message):
            transfer_sources(
                plan_run(config(tmp_path / "cache", source_task=SourceTask.team, source_agent=wanted)), tmp_path
            )
    assert pretrainings == [] and not (tmp_path / "cache").exists()


# name -> (overrides, the error line)
REFUSED = {
    "team_without_transfer": (
        ("transfer.source_task=team",),
        "error: transfer.source_task=team says how the transfer source is pretrained: it needs transfer=on",
    ),
    "shift_without_transfer": (
        ("transfer.source_map_shift=1000",),
        "error: transfer.source_map_shift=1000 says how the transfer source is pretrained: it needs transfer=on",
    ),
    "team_with_source": (
        ("transfer=on", "transfer.source=elsewhere", "transfer.source_task=team"),
        "error: transfer.source_task=team says how the transfer source is pretrained, but "
        "transfer.source=elsewhere is not pretrained: leave one of them unset",
    ),
    "shift_with_source": (
        ("transfer=on", "transfer.source=elsewhere", "transfer.source_map_shift=1000"),
        "error: transfer.source_map_shift=1000 says how the transfer source is pretrained, but "
        "transfer.source=elsewhere is not pretrained: leave one of them unset",
    ),
    "shift_with_layout": (
        ("transfer=on", "env.layout_file=map.txt", "transfer.source_map_shift=1000"),
        "error: transfer.source_map_shift=1000 shifts env.map_seed, which needs a generated map; "
        "env.layout / env.layout_file fix the map",
    ),
    "team_member_missing": (
        ("transfer=on", "transfer.source_task=team", "transfer.source_agent=2"),
        "error: transfer.source_agent=2: the source team (transfer.source_task=team) is this run's "
        "team of 2 agents (0..1), which has no agent 2",
    ),
}


@pytest.fixture(scope="module")
def refused(tmp_path_factory) -> tuple[Path, dict]:
    cwd = tmp_path_factory.mktemp("refused")
    (cwd / "map.txt").write_text(MAP)
    names = list(REFUSED)
    jobs = [
        (cwd, ("agent=qlearning", "transfer.pretrain_steps=50", "total_steps=20", *REFUSED[name][0]), cwd / name)
        for name in names
    ]
    return cwd, dict(zip(names, run_many(jobs, check=False)))


@pytest.mark.slow
@pytest.mark.parametrize("case", list(REFUSED))
def test_each_refusal_is_one_line_and_leaves_nothing(refused, case):
    """Through ``python train.py``: exit code 1, the one ``error:`` line, and nothing left behind."""
    cwd, results = refused
    result = results[case]
    assert result.returncode == 1, result.output
    assert "Traceback" not in result.output
    assert [line for line in result.stderr.splitlines() if line.startswith("error:")] == [REFUSED[case][1]]
    assert not result.run_dir.exists() or list(result.run_dir.iterdir()) == []
    assert sorted(p.name for p in cwd.iterdir()) == sorted(["map.txt"])  # no run, no pretraining cache
