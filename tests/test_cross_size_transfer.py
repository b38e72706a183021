"""Transfer across map sizes, chest counts and team sizes, on hand-built maps.

The 5x5 source map sits at offset (2, 1) inside the 8x8 target map, whose extra chest comes first in
its row-major chest order, so the source's chest is the target's second. Every embedded state's
target observation is written out here column by column, and the source's Q-values are computed from
its checkpoint (a plain MLP, or a dict lookup of the table), without the mapping code.
"""

import logging

import numpy as np
import pytest
import torch
from conftest import reference_mlp

from dqn_transfer.config import AgentConfig, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Engine, Fill, ObsEncoding
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sources.resolve import resolve_source
from dqn_transfer.storage.checkpoint import CheckpointError, load_agent_checkpoint
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer, train
from dqn_transfer.transfer.mapping import TransferError

SOURCE_MAP = "0....\n.....\n..T..\n.....\nX...."  # chest (2, 2), trap (4, 0), start (0, 0)
OFFSET = (2, 1)
TARGET_MAP = "\n".join(
    [
        ".......T",  # the new chest (0, 7): chest 0 of the target
        "........",
        ".0......",  # start 0 on the source's start cell (0, 0) + offset
        "........",
        "...T....",  # the source's chest (2, 2) + offset = (4, 3): chest 1 of the target
        "........",
        ".X.....1",  # the source's trap (4, 0) + offset
        "........",
    ]
)
SOURCE_CELLS = [(r, c) for r in range(5) for c in range(5)]


def config(
    layout: str,
    algorithm: Algorithm,
    *,
    encoding: ObsEncoding = ObsEncoding.onehot,
    steps: int = 0,
    transfer: TransferConfig | None = None,
) -> TrainConfig:
    rows = layout.split("\n")
    env = EnvConfig(
        layout=layout,
        size=len(rows),
        num_treasures=layout.count("T"),
        num_traps=layout.count("X"),
        complexity=0.0,
        obs_encoding=encoding,
    )
    return TrainConfig(
        env=env,
        agent=AgentConfig(
            algorithm=algorithm,
            engine=Engine.numpy,
            learning_starts=20,
            lr=0.3 if Algorithm(algorithm).is_tabular else 1e-3,
        ),
        transfer=transfer or TransferConfig(),
        total_steps=steps,
        eval_every=max(steps, 1),
        eval_episodes=1,
        checkpoint_every=max(steps, 1),
        progress=False,
    )


def trained_source(
    tmp_path, algorithm: Algorithm, encoding: ObsEncoding = ObsEncoding.onehot, layout: str = SOURCE_MAP
):
    """A team run on the source map (so it has a `treasures` input), trained a little."""
    train(plan_run(config(layout, algorithm, encoding=encoding, steps=300)), tmp_path / "source")
    return tmp_path / "source" / "checkpoints" / "agent_0.safetensors"


def transferred(tmp_path, source, algorithm: Algorithm, encoding: ObsEncoding = ObsEncoding.onehot, **transfer):
    """The target run's learner right after the warm start (no training)."""
    settings = TransferConfig(enabled=True, source=str(source), **{"offset": list(OFFSET), **transfer})
    trainer = Trainer(
        plan_run(config(TARGET_MAP, algorithm, encoding=encoding, transfer=settings)),
        tmp_path / "target",
        sources=[source],
    )
    trainer.prepare()
    return trainer.replicas[0].learner


def position(cell, size: int, encoding: ObsEncoding) -> list[float]:
    r, c = cell
    if encoding is ObsEncoding.onehot:
        return [1.0 if i == r * size + c else 0.0 for i in range(size * size)]
    return [r / (size - 1), c / (size - 1)]


def embedded_states(encoding: ObsEncoding):
    """(source obs, target obs) of every embedded state: each source cell, the source chest full or
    taken, and the target's new chest believed full or taken (it must not matter)."""
    for cell in SOURCE_CELLS:
        for chest in (0.0, 1.0):
            for new_chest in (0.0, 1.0):
                source = position(cell, 5, encoding) + [chest]
                target_cell = (cell[0] + OFFSET[0], cell[1] + OFFSET[1])
                yield source, position(target_cell, 8, encoding) + [new_chest, chest]


def target_q(learner, obs: list[float]) -> np.ndarray:
    team = np.zeros((2, len(obs)), dtype=np.float32)
    team[:] = obs
    return learner.q_values(team)[0]


@pytest.mark.parametrize("encoding", [ObsEncoding.onehot, ObsEncoding.coords])
def test_dqn_computes_the_sources_q_values_on_every_embedded_state(tmp_path, encoding):
    source = trained_source(tmp_path, Algorithm.dqn, encoding)
    learner = transferred(tmp_path, source, Algorithm.dqn, encoding)
    reference = reference_mlp(load_agent_checkpoint(source)[0])
    pairs = list(embedded_states(encoding))
    assert len(pairs) == 25 * 4
    with torch.no_grad():
        expected = reference(torch.tensor([s for s, _ in pairs])).numpy()
    got = np.stack([target_q(learner, t) for _, t in pairs])
    # onehot copies weights; coords rescales them (float rounding)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5 if encoding is ObsEncoding.onehot else 1e-4)


@pytest.mark.parametrize("encoding", [ObsEncoding.onehot, ObsEncoding.coords])
def test_a_table_starts_with_the_sources_values_on_every_embedded_state(tmp_path, encoding):
    source = trained_source(tmp_path, Algorithm.sarsa, encoding)
    tensors = load_agent_checkpoint(source)[0]
    table = {key.tobytes(): row for key, row in zip(tensors["keys"], tensors["values"])}
    assert len(table) > 10  # the source visited a fair part of its map
    learner = transferred(tmp_path, source, Algorithm.sarsa, encoding)
    seen = 0
    for source_obs, target_obs in embedded_states(encoding):
        expected = table.get(np.array(source_obs, dtype=np.float32).tobytes())
        seen += expected is not None
        np.testing.assert_array_equal(target_q(learner, target_obs), np.zeros(4) if expected is None else expected)
    assert seen >= len(table)  # every source entry is found (twice: whatever the new chest holds)


def test_cells_outside_the_source_map_read_zero_or_the_nearest_cell(tmp_path):
    source = trained_source(tmp_path, Algorithm.dqn)
    reference = reference_mlp(load_agent_checkpoint(source)[0])
    zero = transferred(tmp_path / "zero", source, Algorithm.dqn)
    nearest = transferred(tmp_path / "nearest", source, Algorithm.dqn, fill=Fill.nearest)
    outside, clamped = (7, 7), (4, 4)  # target (7, 7) is below right of the source's corner (4, 4) + offset
    target_obs = position(outside, 8, ObsEncoding.onehot) + [1.0, 1.0]
    with torch.no_grad():
        at_corner = reference(torch.tensor([position(clamped, 5, ObsEncoding.onehot) + [1.0]])).numpy()[0]
        no_position = reference(torch.tensor([[0.0] * 25 + [1.0]])).numpy()[0]
    np.testing.assert_allclose(target_q(nearest, target_obs), at_corner, rtol=0, atol=1e-5)
    np.testing.assert_allclose(target_q(zero, target_obs), no_position, rtol=0, atol=1e-5)


def test_a_source_chest_without_a_target_chest_is_dropped_with_a_warning(tmp_path, caplog):
    two_chests = "0...T\n.....\n..T..\n.....\nX...."  # (0, 4) + offset = (2, 5): no chest there
    source = trained_source(tmp_path, Algorithm.dqn, layout=two_chests)
    with caplog.at_level(logging.WARNING, logger="dqn_transfer.transfer"):
        learner = transferred(tmp_path, source, Algorithm.dqn)
    assert "drops the source's chest(s) at row 0, col 4" in caplog.text
    reference = reference_mlp(load_agent_checkpoint(source)[0])
    for cell in [(0, 0), (3, 2)]:  # the source reads the dropped chest as taken (0)
        source_obs = position(cell, 5, ObsEncoding.onehot) + [0.0, 1.0]
        target_obs = position((cell[0] + 2, cell[1] + 1), 8, ObsEncoding.onehot) + [1.0, 1.0]
        with torch.no_grad():
            np.testing.assert_allclose(
                target_q(learner, target_obs), reference(torch.tensor([source_obs])).numpy()[0], rtol=0, atol=1e-5
            )


@pytest.mark.parametrize(
    "offset, message",
    [
        (
            (4, 0),
            r"transfer.offset=\[4, 0\] puts the source's 5x5 map off this run's 8x8 map "
            r"\(each offset must be in 0..3\)",
        ),
        ((0, 4), r"offset=\[0, 4\] puts the source's 5x5 map off"),
    ],
)
def test_an_offset_that_pushes_the_source_off_the_map_is_refused(tmp_path, offset, message):
    source = trained_source(tmp_path, Algorithm.sarsa)
    with pytest.raises(TransferError, match=message):
        transferred(tmp_path, source, Algorithm.sarsa, offset=list(offset))


def test_a_source_larger_than_the_target_is_refused(tmp_path):
    source = trained_source(tmp_path, Algorithm.dqn, layout=TARGET_MAP)
    settings = TransferConfig(enabled=True, source=str(source))
    trainer = Trainer(
        plan_run(config(SOURCE_MAP, Algorithm.dqn, transfer=settings)), tmp_path / "target", sources=[source]
    )
    with pytest.raises(TransferError, match="the source's 8x8 map does not fit in this run's 5x5 map"):
        trainer.prepare()


def test_a_larger_team_takes_one_source_agent_per_target(tmp_path):
    train(plan_run(config(TARGET_MAP, Algorithm.dqn, steps=200)), tmp_path / "pair")  # two agents
    three = TARGET_MAP.replace(".......T\n", "2......T\n")
    settings = TransferConfig(enabled=True, source=str(tmp_path / "pair"), source_agent=[1, 0, 1])
    sources = resolve_source(settings, tmp_path, 3)
    assert [p.name for p in sources] == ["agent_1.safetensors", "agent_0.safetensors", "agent_1.safetensors"]
    trainer = Trainer(plan_run(config(three, Algorithm.dqn, transfer=settings)), tmp_path / "trio", sources=[sources])
    trainer.prepare()
    obs = np.zeros((3, 64 + 2), dtype=np.float32)
    obs[:, 8 * 3 + 3] = 1.0  # every agent at (3, 3), both chests full
    obs[:, 64:] = 1.0
    with torch.no_grad():
        per_source = [
            reference_mlp(load_agent_checkpoint(tmp_path / "pair" / "checkpoints" / f"agent_{i}.safetensors")[0])(
                torch.from_numpy(obs[:1])
            )[0]
            for i in (0, 1)
        ]
    got = trainer.replicas[0].learner.q_values(obs)
    for agent, source_agent in enumerate([1, 0, 1]):
        np.testing.assert_allclose(got[agent], per_source[source_agent].numpy(), rtol=0, atol=1e-5)
    assert not np.allclose(per_source[0].numpy(), per_source[1].numpy())  # the two sources tell apart
    info = trainer.replicas[0].transfer_info
    assert [entry["source_agent"] for entry in info["per_target"]] == [1, 0, 1]


@pytest.mark.parametrize(
    "source_agent, message",
    [
        ([0, 1], "lists 2 source agents for 3 target agents"),
        ([0, 5, 0], "has no agent_5.safetensors"),
    ],
)
def test_a_wrong_source_agent_list_is_refused(tmp_path, source_agent, message):
    train(plan_run(config(TARGET_MAP, Algorithm.sarsa, steps=0)), tmp_path / "pair")
    with pytest.raises((TransferError, CheckpointError), match=message):
        resolve_source(
            TransferConfig(enabled=True, source=str(tmp_path / "pair"), source_agent=source_agent), tmp_path, 3
        )
