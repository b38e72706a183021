"""Per-agent sources (``transfer.source_task=per_agent``) and the chest-aware table lookup
(``transfer.chest_aware``), docs/transfer.md.

The worked map: 5x5, agent 0 top-left, agent 1 bottom-right, chest 0 two moves right of agent 0 and
chest 1 two moves left of agent 1 (chests are numbered row-major), no trap, no obstacle::

    0.T..
    .....
    .....
    .....
    ..T.1

So agent 0's nearest chest is chest 0 (2 moves, against 6) and agent 1's is chest 1. A target's
observation is ``position`` (25 one-hot columns, cell ``r * 5 + c``) then ``treasures`` (columns 25
and 26, 1 while a chest is believed full). Sources are pretrained for 200 steps.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    WARM_START_NUMPY_DQN,
    WARM_START_PRETRAIN_STEPS,
    WARM_START_QLEARNING,
    agent_meta,
    warm_start_config,
)
from safetensors.numpy import load_file

import dqn_transfer.sources.resolve
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.config import (
    AgentConfig,
    ConfigError,
    CurriculumConfig,
    ReplicasConfig,
    StageConfig,
    TrainConfig,
    validate,
)
from dqn_transfer.enums import Algorithm, Mode, SourceTask
from dqn_transfer.envs.maps import generate_layout, parse_layout
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sources.resolve import transfer_sources
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train
from dqn_transfer.transfer.mapping import Embedding, MapGeometry, TransferError, transfer_tabular_tensors
from dqn_transfer.transfer.warm_start import source_chest_column

MAP = "0.T..\n.....\n.....\n.....\n..T.1"
# The map agent 1's source plays: agent 1's start is agent 0's (the two digits swapped).
MAP_FROM_1 = "1.T..\n.....\n.....\n.....\n..T.0"
START = {0: 0, 1: 24}  # each agent's start cell, r * 5 + c
CELLS, CHESTS = 25, 2
PRETRAIN_STEPS = WARM_START_PRETRAIN_STEPS
QLEARNING, NUMPY_DQN = WARM_START_QLEARNING, WARM_START_NUMPY_DQN


def config(cache: Path, *, agent: AgentConfig = QLEARNING, env: EnvConfig | None = None, **transfer) -> TrainConfig:
    return warm_start_config(cache, MAP, 0, agent, env, **transfer)


def entries(cache: Path) -> list[str]:
    return sorted(p.name for p in cache.iterdir() if p.is_dir() and not p.name.startswith("."))


def onehot(cell: int, treasures: tuple[float, ...] = ()) -> np.ndarray:
    return np.concatenate([np.eye(CELLS, dtype=np.float32)[cell], np.asarray(treasures, dtype=np.float32)])


def table_value(keys: np.ndarray, values: np.ndarray, key: np.ndarray) -> np.ndarray | None:
    """The row of ``values`` whose key is ``key`` exactly (a table's lookup, written out), None if none."""
    rows = np.flatnonzero((keys == key).all(axis=1))
    return values[rows[0]] if rows.size else None


def start_value(target: dict, cell: int, treasures: tuple[float, float]) -> np.ndarray | None:
    """What a transferred table holds for an unseen observation: its fallback's row for ``obs[projection]``."""
    obs = onehot(cell, treasures)
    return table_value(target["fallback_keys"], target["fallback_values"], obs[target["fallback_projection"]])


@pytest.fixture
def pretrainings(monkeypatch) -> list[TrainConfig]:
    """Every pretraining run started from now on (its config), each still carried out."""
    real, runs = dqn_transfer.sources.resolve.train_on_cores, []

    def counted(plan, *args, **kwargs):
        runs.append(plan.config)
        return real(plan, *args, **kwargs)

    monkeypatch.setattr(dqn_transfer.sources.resolve, "train_on_cores", counted)
    return runs


# ---------------------------------------------------------------------------------- the map


def test_the_nearest_chest_and_a_map_started_from_another_agent():
    grid = parse_layout(MAP)
    assert grid.nearest_chest((0, 0)) == 0 and grid.nearest_chest((4, 4)) == 1
    assert parse_layout("0.T\n...\nT..").nearest_chest((0, 0)) == 0  # 2 moves each: the lower number
    assert grid.with_start_of(0) is grid
    from_1 = grid.with_start_of(1)
    assert from_1.layout == MAP_FROM_1
    assert from_1.starts == ((4, 4), (0, 0)) and from_1.chests == grid.chests


# ---------------------------------------------------------------------------------- per-agent sources


def test_each_target_starts_from_the_source_pretrained_from_its_own_start(tmp_path, pretrainings, caplog):
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    cache = tmp_path / "cache"
    own = config(cache, source_task=SourceTask.per_agent)
    [[source_0, source_1]] = transfer_sources(plan_run(own), tmp_path)
    # Two sources, two cache entries, two pretrainings on TreasureHunt-v0: agent 1's from its own start.
    assert len(pretrainings) == 2 and len(entries(cache)) == 2
    assert source_0.parent.parent != source_1.parent.parent
    for source, layout in ((source_0, MAP), (source_1, MAP_FROM_1)):
        meta = agent_meta(source)
        assert (meta["env"]["layout"], meta["source_task"], meta["steps"]) == (layout, True, PRETRAIN_STEPS)
        assert meta["obs_layout"] == [["position", CELLS]]
    assert "the source of agent 1 learns TreasureHunt-v0 from agent 1's start" in caplog.text

    # Agent 0's source is the single source: the same entry, reused, as are both on a second run.
    [[single, _]] = transfer_sources(plan_run(config(cache)), tmp_path)
    assert single == source_0
    caplog.clear()
    assert transfer_sources(plan_run(own), tmp_path) == [[source_0, source_1]]
    assert len(pretrainings) == 2 and caplog.text.count("reusing the pretrained source") == 2

    # The warm start: each target's start values at its own start are its own source's values there.
    train(plan_run(own), tmp_path / "run", sources=[[source_0, source_1]])
    for agent, source in enumerate((source_0, source_1)):
        learned = load_file(str(source))
        own_value = table_value(learned["keys"], learned["values"], onehot(START[agent]))
        assert own_value is not None and (own_value != 0).any()  # it learned from where it started
        target = load_file(str(tmp_path / "run" / "checkpoints" / f"agent_{agent}.safetensors"))
        np.testing.assert_array_equal(start_value(target, START[agent], (1.0, 1.0)), own_value)
    record = agent_meta(tmp_path / "run" / "checkpoints" / "agent_1.safetensors")["transfer"]
    assert [(t["source"], t["source_agent"], t["source_start"]) for t in record["per_target"]] == [
        (str(source_0.resolve()), 0, [0, 0]),
        (str(source_1.resolve()), 0, [4, 4]),
    ]


def test_only_the_targets_get_sources_and_replicas_get_their_own(tmp_path, pretrainings):
    cache = tmp_path / "cache"
    one = config(cache, source_task=SourceTask.per_agent, targets=[1])
    [[source_1]] = transfer_sources(plan_run(one), tmp_path)
    assert agent_meta(source_1)["env"]["layout"] == MAP_FROM_1 and len(pretrainings) == 1

    # Two seeds: per target agent, the seeds' missing sources are pretrained as one batch (agent 0's two;
    # agent 1's seed 0 is cached, so its seed 1 alone), each the lone run's.
    batch = dataclasses.replace(config(cache, source_task=SourceTask.per_agent), replicas=ReplicasConfig(seeds=2))
    per_replica = transfer_sources(plan_run(batch), tmp_path)
    assert [(run.replicas.seeds, run.seed) for run in pretrainings[1:]] == [(2, 0), (1, 1)]
    assert len({source for sources in per_replica for source in sources}) == 4
    assert per_replica[0][1] == source_1  # seed 0's agent-1 source: the same key as before
    for seed, sources in enumerate(per_replica):
        assert [agent_meta(s)["env"]["layout"] for s in sources] == [MAP, MAP_FROM_1]
        assert [agent_meta(s)["seed"] for s in sources] == [seed, seed]


def test_a_shifted_per_agent_source_starts_from_the_agent_start_of_the_shifted_map(tmp_path):
    generated = dict(size=5, num_treasures=2, num_traps=1, num_agents=2, complexity=0.0)
    run = config(tmp_path / "cache", env=EnvConfig(**generated, map_seed=3), source_task=SourceTask.per_agent)
    run = dataclasses.replace(run, transfer=dataclasses.replace(run.transfer, source_map_shift=1000))
    [[source_0, source_1]] = transfer_sources(plan_run(run), tmp_path)
    shifted = generate_layout(5, 2, 1, 2, 0.0, seed=1003)
    swapped = shifted.replace("0", "_").replace("1", "0").replace("_", "1")
    assert [agent_meta(s)["env"]["layout"] for s in (source_0, source_1)] == [shifted, swapped]


def test_per_agent_dqn_targets_compute_their_own_source(tmp_path):
    own = config(tmp_path / "cache", agent=NUMPY_DQN, source_task=SourceTask.per_agent)
    sources = transfer_sources(plan_run(own), tmp_path)
    train(plan_run(own), tmp_path / "run", sources=sources)
    weights = [load_file(str(source))["q.layers.0.weight"] for source in sources[0]]
    assert not np.array_equal(*weights)
    for agent, weight in enumerate(weights):
        target = load_file(str(tmp_path / "run" / "checkpoints" / f"agent_{agent}.safetensors"))["q.layers.0.weight"]
        np.testing.assert_array_equal(target[:, :CELLS], weight)  # position: the source's own
        assert not target[:, CELLS:].any()  # treasures: a new segment, zero input weights


# ---------------------------------------------------------------------------------- chest-aware lookup


def test_a_gated_source_value_applies_only_while_the_gate_reads_a_full_chest():
    """A hand-made lone source: cell 0 worth [1, 2, 3, 4], cell 1 worth [5, 6, 7, 8]; gated by column 26
    (chest 1's `treasures` entry)."""
    source = {
        "keys": np.eye(CELLS, dtype=np.float32)[[0, 1]],
        "values": np.array([[1, 2, 3, 4], [5, 6, 7, 8]], dtype=np.float32),
    }
    target_layout = [("position", CELLS), ("treasures", CHESTS)]
    mapped = transfer_tabular_tensors(source, [("position", CELLS)], target_layout, num_actions=4, gate_column=26)
    np.testing.assert_array_equal(mapped["fallback_projection"], [*range(CELLS), 26])
    learner = TabularLearner(2, target_layout, 4, AgentConfig(algorithm=Algorithm.sarsa))
    learner.load_agent_tensors(1, mapped)
    for treasures, expected in [
        ((1.0, 1.0), [1, 2, 3, 4]),  # both full: the source's values
        ((0.0, 1.0), [1, 2, 3, 4]),  # the other chest taken: still the source's
        ((1.0, 0.0), [0, 0, 0, 0]),  # its chest taken: the empty table's default
        ((0.0, 0.0), [0, 0, 0, 0]),
    ]:
        np.testing.assert_array_equal(learner.agent_q_values(1, onehot(0, treasures)), expected)
    np.testing.assert_array_equal(learner.agent_q_values(1, onehot(1, (1.0, 1.0))), [5, 6, 7, 8])
    np.testing.assert_array_equal(learner.agent_q_values(1, onehot(2, (1.0, 1.0))), [0, 0, 0, 0])  # unknown cell
    # Without the gate, today's lookup: by position alone.
    plain = transfer_tabular_tensors(source, [("position", CELLS)], target_layout, num_actions=4)
    learner.load_agent_tensors(0, plain)
    np.testing.assert_array_equal(learner.agent_q_values(0, onehot(0, (1.0, 0.0))), [1, 2, 3, 4])


def test_chest_aware_per_agent_targets_watch_their_own_sources_chest(tmp_path):
    aware = config(tmp_path / "cache", source_task=SourceTask.per_agent, chest_aware=True)
    aware = dataclasses.replace(aware, env=dataclasses.replace(aware.env, mode=Mode.cooperative))
    sources = transfer_sources(plan_run(aware), tmp_path)
    train(plan_run(aware), tmp_path / "run", sources=sources)
    for agent, (own_chest, other) in enumerate([((0.0, 1.0), (1.0, 0.0)), ((1.0, 0.0), (0.0, 1.0))]):
        target = load_file(str(tmp_path / "run" / "checkpoints" / f"agent_{agent}.safetensors"))
        # Agent 0 watches chest 0 (column 25), agent 1 chest 1 (column 26): the nearest to each one's start.
        np.testing.assert_array_equal(target["fallback_projection"], [*range(CELLS), CELLS + agent])
        learned = load_file(str(sources[0][agent]))
        value = table_value(learned["keys"], learned["values"], onehot(START[agent]))
        np.testing.assert_array_equal(start_value(target, START[agent], (1.0, 1.0)), value)
        np.testing.assert_array_equal(start_value(target, START[agent], other), value)  # the other chest taken
        assert start_value(target, START[agent], own_chest) is None  # its own taken: no prior, the default 0


def test_a_source_chest_the_target_map_lacks_is_refused():
    source = parse_layout("0T.\n...\n...")
    target = parse_layout("0..\n...\n..T")
    geometry = [MapGeometry(3, grid.chests, "onehot", np.eye(9, dtype=np.float32)) for grid in (source, target)]
    embedding = Embedding(*geometry)
    with pytest.raises(TransferError, match=r"the source's chest \(row 0, col 1, the nearest to its start\) has no"):
        source_chest_column(source.starts[0], source, embedding, [("position", 9), ("treasures", 1)])


@pytest.mark.parametrize(
    "change, message",
    [
        ({"transfer": {"enabled": False}}, "it needs transfer=on"),
        ({"agent": NUMPY_DQN}, "it needs agent=sarsa or agent=qlearning, not agent=dqn"),
        ({"transfer": {"source_task": SourceTask.team}}, "with transfer.source_task=team"),
        ({"transfer": {"source": "elsewhere"}}, "not transfer.source=elsewhere"),
        (
            {"curriculum": CurriculumConfig(stages=[StageConfig(env={"size": 4}, steps=10)])},
            "a curriculum's run starts from its last stage",
        ),
    ],
)
def test_chest_aware_is_refused_where_it_cannot_apply(tmp_path, change, message):
    aware = config(tmp_path, chest_aware=True)
    transfer = dataclasses.replace(aware.transfer, **change.pop("transfer", {}))
    aware = dataclasses.replace(aware, transfer=transfer, **change)
    with pytest.raises(ConfigError, match="^transfer.chest_aware=true uses a lone source's values only while"):
        validate(aware)
    with pytest.raises(ConfigError, match=message):
        validate(aware)
