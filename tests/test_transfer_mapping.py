"""Weight-transfer mapping: function preservation, segment matching by name, errors, tabular fallback.

Reference networks are plain ``nn.Sequential`` MLPs loaded from the tensor dicts, and source
observations are assembled segment by segment in the test, so nothing here relies on the code under test
to say which column is which.
"""

import numpy as np
import pytest
import torch
from conftest import reference_mlp as mlp
from torch import nn

from dqn_transfer.transfer.mapping import (
    TransferError,
    input_map,
    plan_segment_mapping,
    segment_slices,
    transfer_dqn_tensors,
    transfer_tabular_tensors,
)

NUM_ACTIONS = 4
HIDDEN = [32, 16]


def dqn_transfer(source: dict[str, torch.Tensor], *args, **kwargs) -> dict[str, torch.Tensor]:
    """The mapping takes and gives numpy arrays; the references here are torch modules."""
    out = transfer_dqn_tensors({name: t.numpy() for name, t in source.items()}, *args, **kwargs)
    return {name: torch.from_numpy(a) for name, a in out.items()}


def tabular_transfer(source: dict[str, torch.Tensor], *args, **kwargs) -> dict[str, torch.Tensor]:
    out = transfer_tabular_tensors({name: t.numpy() for name, t in source.items()}, *args, **kwargs)
    return {name: torch.from_numpy(a) for name, a in out.items()}


def random_dqn_tensors(in_dim: int, hidden: list[int], gen: torch.Generator) -> dict[str, torch.Tensor]:
    """Online and (different) target MLP tensors in the learners' naming, at nn.Linear's scale."""
    sizes = [in_dim, *hidden, NUM_ACTIONS]
    tensors = {}
    for net in ("q", "target"):
        for l, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:])):
            tensors[f"{net}.layers.{l}.weight"] = torch.randn(fan_out, fan_in, generator=gen) / fan_in**0.5
            tensors[f"{net}.layers.{l}.bias"] = torch.randn(fan_out, generator=gen) / fan_in**0.5
    return tensors


def random_segments(layout, batch: int, gen: torch.Generator) -> dict[str, torch.Tensor]:
    """One-hot ``position``, random binary everything else."""
    segments = {}
    for name, size in layout:
        if name == "position":
            segments[name] = nn.functional.one_hot(torch.randint(size, (batch,), generator=gen), size).float()
        else:
            segments[name] = torch.randint(2, (batch, size), generator=gen).float()
    return segments


def concat(segments: dict[str, torch.Tensor], layout) -> torch.Tensor:
    return torch.cat([segments[name] for name, _ in layout], dim=1)


POSITION = ("position", 36)
TREASURES = ("treasures", 3)
ASSIGNMENT = ("assignment", 3)
VIEW = ("view", 27)


@pytest.mark.parametrize(
    "source_layout, target_layout",
    [
        ([POSITION], [POSITION, TREASURES]),
        ([POSITION], [POSITION, TREASURES, ASSIGNMENT]),
        ([POSITION, VIEW], [POSITION, TREASURES, VIEW]),
        ([POSITION, TREASURES], [TREASURES, ASSIGNMENT, POSITION]),  # reordered: mapped by name
    ],
)
def test_dqn_transfer_preserves_q_values(source_layout, target_layout):
    gen = torch.Generator().manual_seed(0)
    source = random_dqn_tensors(sum(size for _, size in source_layout), HIDDEN, gen)
    out = dqn_transfer(source, source_layout, target_layout, HIDDEN, NUM_ACTIONS)

    segments = random_segments(target_layout, 100, gen)
    with torch.no_grad():
        q_target = mlp(out)(concat(segments, target_layout))
        q_source = mlp(source)(concat(segments, source_layout))
    torch.testing.assert_close(q_target, q_source, atol=1e-6, rtol=0)
    assert q_target.std() > 0.1  # a real network, not a constant


def test_dqn_transfer_target_only_columns_are_zero_and_target_net_copies_online():
    gen = torch.Generator().manual_seed(1)
    source = random_dqn_tensors(36, HIDDEN, gen)
    out = dqn_transfer(source, [POSITION], [TREASURES, POSITION], HIDDEN, NUM_ACTIONS)

    weight = out["q.layers.0.weight"]
    assert weight.shape == (32, 39)
    assert torch.equal(weight[:, :3], torch.zeros(32, 3))
    assert torch.equal(weight[:, 3:], source["q.layers.0.weight"])
    for l in (1, 2):
        assert torch.equal(out[f"q.layers.{l}.weight"], source[f"q.layers.{l}.weight"])
    assert sorted(out) == sorted(source)
    for key in out:
        if key.startswith("target."):
            online = out["q" + key.removeprefix("target")]
            assert torch.equal(out[key], online)
            assert out[key].data_ptr() != online.data_ptr()  # safetensors refuses shared storage


def test_dqn_transfer_without_hidden_layers():
    gen = torch.Generator().manual_seed(2)
    source = random_dqn_tensors(36, [], gen)
    out = dqn_transfer(source, [POSITION], [POSITION, TREASURES], [], NUM_ACTIONS)
    segments = random_segments([POSITION, TREASURES], 20, gen)
    with torch.no_grad():
        torch.testing.assert_close(
            mlp(out)(concat(segments, [POSITION, TREASURES])), mlp(source)(segments["position"]), atol=1e-6, rtol=0
        )


def test_dropped_source_segment_is_reported_and_acts_as_zeros():
    gen = torch.Generator().manual_seed(3)
    source_layout, target_layout = [POSITION, VIEW], [POSITION, TREASURES]
    plan = plan_segment_mapping(source_layout, target_layout)
    assert plan.dropped == ("view",)
    assert plan.target_only == ("treasures",)

    source = random_dqn_tensors(63, HIDDEN, gen)
    with pytest.warns(UserWarning, match="view"):
        out = dqn_transfer(source, source_layout, target_layout, HIDDEN, NUM_ACTIONS)
    segments = random_segments(target_layout, 50, gen)
    segments["view"] = torch.zeros(50, 27)
    with torch.no_grad():
        torch.testing.assert_close(
            mlp(out)(concat(segments, target_layout)), mlp(source)(concat(segments, source_layout)), atol=1e-6, rtol=0
        )


def test_plan_maps_columns_by_name():
    source = [("a", 2), ("b", 3), ("c", 1)]  # columns a: 0-1, b: 2-4, c: 5
    target = [("c", 1), ("d", 2), ("a", 2)]  # columns c: 0, d: 1-2, a: 3-4
    assert segment_slices(target) == {"c": slice(0, 1), "d": slice(1, 3), "a": slice(3, 5)}
    plan = plan_segment_mapping(source, target)
    assert [(s.name, s.source, s.target) for s in plan.shared] == [
        ("a", slice(0, 2), slice(3, 5)),
        ("c", slice(5, 6), slice(0, 1)),
    ]
    assert (plan.source_dim, plan.target_dim) == (6, 5)
    assert plan.target_only == ("d",)
    assert plan.dropped == ("b",)
    # source observation = M @ target observation: a: target 3-4 -> source 0-1, c: target 0 -> source 5
    matrix, shift = input_map(plan)
    expected = np.zeros((6, 5))
    expected[0, 3] = expected[1, 4] = expected[5, 0] = 1.0
    np.testing.assert_array_equal(matrix, expected)
    np.testing.assert_array_equal(shift, np.zeros(6))


def test_plan_accepts_layouts_read_back_from_json():
    plan = plan_segment_mapping([["position", 36]], [["position", 36], ["treasures", 3]])
    assert plan.target_only == ("treasures",)


def test_segment_size_mismatch_is_an_error():
    with pytest.raises(TransferError, match=r"segment 'position' has 36 values in the source and 64 in the target"):
        plan_segment_mapping([("position", 36)], [("position", 64), TREASURES])


@pytest.mark.parametrize(
    "source_layout, target_layout, message",
    [
        ([POSITION], [TREASURES], "share no obs segment"),
        ([POSITION, POSITION], [POSITION], "repeats segment"),
    ],
)
def test_unmappable_layouts_are_errors(source_layout, target_layout, message):
    with pytest.raises(TransferError, match=message):
        plan_segment_mapping(source_layout, target_layout)


def test_hidden_shape_mismatch_is_an_error():
    source = random_dqn_tensors(36, [64, 64], torch.Generator().manual_seed(4))
    with pytest.raises(TransferError, match=r"hidden layers differ: source \[64, 64\], target \[128, 128\]"):
        dqn_transfer(source, [POSITION], [POSITION, TREASURES], [128, 128], NUM_ACTIONS)


def test_num_actions_mismatch_is_an_error():
    source = random_dqn_tensors(36, HIDDEN, torch.Generator().manual_seed(5))
    with pytest.raises(TransferError, match="number of actions differs: source 4, target 5"):
        dqn_transfer(source, [POSITION], [POSITION, TREASURES], HIDDEN, 5)


def test_source_network_not_matching_its_layout_is_an_error():
    source = random_dqn_tensors(40, HIDDEN, torch.Generator().manual_seed(6))
    with pytest.raises(TransferError, match="source network takes 40 inputs but its obs layout has 36"):
        dqn_transfer(source, [POSITION], [POSITION, TREASURES], HIDDEN, NUM_ACTIONS)


def test_tabular_tensors_are_not_a_dqn_source():
    source = {"keys": torch.zeros(1, 36), "values": torch.zeros(1, 4)}
    with pytest.raises(TransferError, match="not a DQN checkpoint"):
        dqn_transfer(source, [POSITION], [POSITION], HIDDEN, NUM_ACTIONS)


# ------------------------------------------------------------------------------------------- tabular

TABLE_KEYS = torch.tensor([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0]])
TABLE_VALUES = torch.tensor([[1.0, 2, 3, 4], [5, 6, 7, 8], [-1, -2, -3, -4]])


def lookup(out: dict[str, torch.Tensor], obs: torch.Tensor) -> torch.Tensor | None:
    """The fallback lookup the tabular learner does for an unseen observation."""
    key = obs[out["fallback_projection"]]
    for row, values in zip(out["fallback_keys"], out["fallback_values"]):
        if torch.equal(row, key):
            return values
    return None


def test_tabular_transfer_puts_the_source_table_in_the_fallback():
    source = {"keys": TABLE_KEYS, "values": TABLE_VALUES}
    out = tabular_transfer(source, [("position", 4)], [("treasures", 2), ("position", 4)], num_actions=4)

    assert out["keys"].shape == (0, 6) and out["keys"].dtype == torch.float32
    assert out["values"].shape == (0, 4) and out["values"].dtype == torch.float32
    assert torch.equal(out["fallback_keys"], TABLE_KEYS)
    assert torch.equal(out["fallback_values"], TABLE_VALUES)
    assert out["fallback_projection"].tolist() == [2, 3, 4, 5]
    assert out["fallback_projection"].dtype == torch.int64
    # Target observation: treasures (1, 0), position cell 2 -> the source's values for cell 2.
    assert torch.equal(lookup(out, torch.tensor([1.0, 0, 0, 0, 1, 0])), TABLE_VALUES[1])
    assert lookup(out, torch.tensor([1.0, 0, 0, 0, 0, 1])) is None  # cell 3 unseen by the source too


def test_tabular_dropped_segment_averages_merged_keys():
    # position (3) + treasures (1); treasures is dropped, so keys 0 and 2 merge into position cell 0.
    source = {
        "keys": torch.tensor([[1.0, 0, 0, 1], [0, 1, 0, 1], [1, 0, 0, 0], [0, 0, 1, 0]]),
        "values": torch.tensor([[1.0, 2], [5, 5], [3, 6], [7, 0]]),
    }
    with pytest.warns(UserWarning, match="treasures"):
        out = tabular_transfer(source, [("position", 3), ("treasures", 1)], [("position", 3), ("view", 2)])
    assert out["fallback_keys"].tolist() == [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    assert out["fallback_values"].tolist() == [[2, 4], [5, 5], [7, 0]]
    assert out["fallback_projection"].tolist() == [0, 1, 2]


def test_tabular_transfer_composes_a_transferred_source_with_an_empty_table():
    # The source is itself a transfer target that never trained: empty table, fallback on position.
    source_layout = [("treasures", 1), ("position", 3)]
    source = {
        "keys": torch.zeros(0, 4),
        "values": torch.zeros(0, 2),
        "fallback_keys": torch.tensor([[1.0, 0, 0], [0, 0, 1]]),
        "fallback_values": torch.tensor([[1.0, 2], [3, 4]]),
        "fallback_projection": torch.tensor([1, 2, 3]),
    }
    out = tabular_transfer(source, source_layout, [("position", 3), ("assignment", 1), ("treasures", 1)])
    assert torch.equal(out["fallback_keys"], source["fallback_keys"])
    assert torch.equal(out["fallback_values"], source["fallback_values"])
    assert out["fallback_projection"].tolist() == [0, 1, 2]
    assert out["keys"].shape == (0, 5)


def test_tabular_chained_transfer_keeps_the_sources_lookup_order():
    # A transferred source that then learned: its own table first, then its fallback, each re-keyed.
    source = {
        "keys": torch.tensor([[0.0, 1, 0, 0]]),  # treasures 0, position cell 0
        "values": torch.tensor([[9.0, 9]]),
        "fallback_keys": torch.tensor([[1.0, 0, 0]]),  # on the source's position columns 1-3
        "fallback_values": torch.tensor([[1.0, 2]]),
        "fallback_projection": torch.tensor([1, 2, 3]),
    }
    with pytest.warns(UserWarning, match="treasures"):
        out = tabular_transfer(source, [("treasures", 1), ("position", 3)], [("position", 3)])
    assert out["fallback_keys"].tolist() == [[1.0, 0, 0]] and out["fallback_values"].tolist() == [[9.0, 9]]
    assert out["fallback_projection"].tolist() == [0, 1, 2]
    assert out["fallback1_keys"].tolist() == [[1.0, 0, 0]] and out["fallback1_values"].tolist() == [[1.0, 2]]
    assert out["fallback1_projection"].tolist() == [0, 1, 2]
    assert "fallback2_keys" not in out


def test_tabular_key_width_not_matching_layout_is_an_error():
    source = {"keys": TABLE_KEYS, "values": TABLE_VALUES}
    with pytest.raises(TransferError, match="keys have shape \\[3, 4\\] but its obs layout has 5 values"):
        tabular_transfer(source, [("position", 5)], [("position", 5)])


def test_tabular_num_actions_mismatch_is_an_error():
    source = {"keys": TABLE_KEYS, "values": TABLE_VALUES}
    with pytest.raises(TransferError, match="number of actions differs: source 4, target 5"):
        tabular_transfer(source, [("position", 4)], [("position", 4)], num_actions=5)
