"""Map a pretrained agent's tensors onto a target agent whose observation has other segments.

An observation is the concatenation of named segments (``position``, ``treasures``, ``assignment``,
``view``); a layout lists them as ``(name, size)`` in order. Transfer matches segments **by name**, so
the source and the target may order them differently:

- a segment both have is copied (its input weights / its key columns);
- a segment only the target has (``treasures`` when going from the single-agent MDP to the expanded
  state) gets **zero input weights**. The transferred network then ignores it at step 0 and computes
  exactly the source's Q-values: a function-preserving expansion, so what the agent learned on the
  MDP carries over unchanged into the expanded state, and training only has to learn how the new
  segments should change it;
- a segment only the source has is dropped, with a warning (the network then behaves as if that
  segment were all zeros);
- a shared segment of a different size (another map size, treasure count or view radius), a different
  hidden shape or a different number of actions cannot be mapped and raises :class:`TransferError`.

Tensor names follow the learners: DQN ``q.layers.{l}.weight`` ``[out, in]`` / ``q.layers.{l}.bias``
``[out]`` and the same under ``target.``; tabular ``keys`` ``[N, D]`` / ``values`` ``[N, A]`` plus an
optional fallback table (``fallback_keys`` ``[M, Ds]``, ``fallback_values`` ``[M, A]``,
``fallback_projection`` ``[Ds]`` int64) consulted for an unseen observation ``x`` via
``x[fallback_projection]``.

This module is pure tensor bookkeeping: the orchestration (finding or pretraining the source,
caching) lives in :mod:`dqn_transfer.sources` and :mod:`dqn_transfer.warm_start`.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

Layout = Sequence[tuple[str, int]]

# Likely cause of a size mismatch, per segment the env produces; shown to the user with the error.
_SIZE_MISMATCH_HINTS = {
    "position": "different map size or obs_encoding?",
    "treasures": "different number of treasures?",
    "assignment": "different number of treasures?",
    "view": "different view_radius?",
}
_LAYER_WEIGHT = re.compile(r"^q\.layers\.(\d+)\.weight$")


class TransferError(ValueError):
    """A source cannot be mapped onto the target; the message is one user-facing line."""


def _normalise_layout(layout: Layout, which: str) -> list[tuple[str, int]]:
    """Accept lists of pairs as read back from JSON meta; refuse duplicated or negative segments."""
    pairs = [(str(name), int(size)) for name, size in layout]
    names = [name for name, _ in pairs]
    duplicated = sorted({name for name in names if names.count(name) > 1})
    if duplicated:
        raise TransferError(f"{which} obs layout repeats segment(s) {duplicated}")
    negative = [name for name, size in pairs if size < 0]
    if negative:
        raise TransferError(f"{which} obs layout has negative size for segment(s) {negative}")
    return pairs


def segment_slices(layout: Layout) -> dict[str, slice]:
    """Column range of each segment in the flat observation (segments are concatenated in order)."""
    slices: dict[str, slice] = {}
    start = 0
    for name, size in _normalise_layout(layout, "the"):
        slices[name] = slice(start, start + size)
        start += size
    return slices


@dataclass(frozen=True)
class SharedSegment:
    """A segment present in both layouts, with its column range on each side."""

    name: str
    size: int
    source: slice
    target: slice


@dataclass(frozen=True)
class SegmentPlan:
    """How source observation columns map onto target columns.

    ``shared`` is in source order, so ``source_columns`` is increasing and restricting a target
    observation to ``projection`` gives the source observation minus its dropped segments.
    """

    source_dim: int
    target_dim: int
    shared: tuple[SharedSegment, ...]
    target_only: tuple[str, ...]
    dropped: tuple[str, ...]

    @property
    def source_columns(self) -> np.ndarray:
        """Source columns that are kept (int64, increasing)."""
        return _concat_ranges([seg.source for seg in self.shared])

    @property
    def projection(self) -> np.ndarray:
        """Target column of each kept source column (int64, aligned with ``source_columns``)."""
        return _concat_ranges([seg.target for seg in self.shared])

    def source_to_target(self) -> np.ndarray:
        """Target column of every source column, -1 for columns of dropped segments."""
        mapping = np.full(self.source_dim, -1, dtype=np.int64)
        mapping[self.source_columns] = self.projection
        return mapping


def _concat_ranges(slices: list[slice]) -> np.ndarray:
    if not slices:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.arange(s.start, s.stop, dtype=np.int64) for s in slices])


def plan_segment_mapping(source_layout: Layout, target_layout: Layout) -> SegmentPlan:
    """Match segments by name; refuse a shared segment whose size differs (nothing sensible to copy)."""
    source = _normalise_layout(source_layout, "source")
    target = _normalise_layout(target_layout, "target")
    source_slices, target_slices = segment_slices(source), segment_slices(target)
    target_sizes = dict(target)
    shared = []
    for name, size in source:
        if name not in target_sizes:
            continue
        if target_sizes[name] != size:
            hint = _SIZE_MISMATCH_HINTS.get(name)
            raise TransferError(
                f"segment '{name}' has {size} values in the source and {target_sizes[name]} in the target"
                + (f" ({hint})" if hint else "")
            )
        shared.append(SharedSegment(name, size, source_slices[name], target_slices[name]))
    if not shared:
        raise TransferError(
            f"source and target share no obs segment (source {[n for n, _ in source]}, "
            f"target {[n for n, _ in target]}): nothing to transfer"
        )
    return SegmentPlan(
        source_dim=sum(size for _, size in source),
        target_dim=sum(size for _, size in target),
        shared=tuple(shared),
        target_only=tuple(name for name, _ in target if name not in source_slices),
        dropped=tuple(name for name, _ in source if name not in target_sizes),
    )


def _warn_dropped(plan: SegmentPlan) -> None:
    if plan.dropped:
        warnings.warn(
            f"transfer drops source-only obs segment(s) {list(plan.dropped)}: the target has no such input",
            stacklevel=3,
        )


# --------------------------------------------------------------------------------------------- DQN


def _dqn_layers(tensors: Mapping[str, np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The online network's (weight, bias) per layer, checked to be a complete MLP."""
    indices = sorted(int(m.group(1)) for key in tensors if (m := _LAYER_WEIGHT.match(key)))
    if not indices:
        raise TransferError("source has no DQN tensors ('q.layers.0.weight' missing): not a DQN checkpoint?")
    if indices != list(range(len(indices))):
        raise TransferError(f"source DQN layers are not numbered 0..L-1: found {indices}")
    layers = []
    for l in indices:
        bias_key = f"q.layers.{l}.bias"
        if bias_key not in tensors:
            raise TransferError(f"source DQN tensor '{bias_key}' is missing")
        layers.append((tensors[f"q.layers.{l}.weight"], tensors[bias_key]))
    return layers


def transfer_dqn_tensors(
    source_tensors: Mapping[str, np.ndarray],
    source_layout: Layout,
    target_layout: Layout,
    target_hidden: Sequence[int],
    num_actions: int,
) -> dict[str, np.ndarray]:
    """Target-shaped ``q.*`` and ``target.*`` tensors computing the source's Q-function.

    Only the first layer sees the observation, so only its weight changes shape: it starts at zero
    and receives the source's columns of every shared segment at their target columns. Target-only
    segments keep zero weights, so for any target observation ``x`` the network returns the
    source's Q-values on ``x`` restricted to the shared segments (exactly, if the source has no
    dropped segment). Deeper layers and biases are copied. The target network is a copy of the
    transferred online network (not of the source's target), as after a hard update.
    """
    plan = plan_segment_mapping(source_layout, target_layout)
    layers = _dqn_layers(source_tensors)
    source_in = layers[0][0].shape[1]
    if source_in != plan.source_dim:
        raise TransferError(
            f"source network takes {source_in} inputs but its obs layout has {plan.source_dim} values"
        )
    source_hidden = [weight.shape[0] for weight, _ in layers[:-1]]
    if source_hidden != list(target_hidden):
        raise TransferError(f"hidden layers differ: source {source_hidden}, target {list(target_hidden)}")
    source_actions = layers[-1][0].shape[0]
    if source_actions != num_actions:
        raise TransferError(f"number of actions differs: source {source_actions}, target {num_actions}")
    _warn_dropped(plan)

    first_weight = np.asarray(layers[0][0])
    expanded = np.zeros((first_weight.shape[0], plan.target_dim), dtype=first_weight.dtype)
    expanded[:, plan.projection] = first_weight[:, plan.source_columns]

    out: dict[str, np.ndarray] = {}
    for l, (weight, bias) in enumerate(layers):
        weight = expanded if l == 0 else weight
        for net in ("q", "target"):
            # Separate contiguous copies: the learner may keep what it is given.
            out[f"{net}.layers.{l}.weight"] = np.array(weight, order="C")
            out[f"{net}.layers.{l}.bias"] = np.array(bias, order="C")
    return out


# ----------------------------------------------------------------------------------------- tabular


def _project_table(
    keys: np.ndarray, values: np.ndarray, columns: np.ndarray, plan: SegmentPlan
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Restrict a table keyed on source ``columns`` to the kept ones; average rows that then collide.

    Dropping a segment merges keys that differed only there. Their Q-values are averaged (mean over
    the visited source keys, first-occurrence order): the mean estimates the value across the
    contexts the source saw, where the max would carry the optimistic bias of the luckiest one.
    Rows collide when their kept columns are byte-identical, the equality the tabular learner uses.
    Returns (keys, values, target column of each key column).
    """
    target_of = plan.source_to_target()[columns]
    kept = target_of >= 0
    restricted = np.ascontiguousarray(keys[:, kept])
    rows = restricted.view(np.dtype((np.void, restricted.dtype.itemsize * restricted.shape[1]))).ravel()
    _, first_rows, inverse = np.unique(rows, return_index=True, return_inverse=True)
    order = np.argsort(first_rows)  # unique() sorts by bytes; restore first-occurrence order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    groups, first_rows = rank[inverse.ravel()], first_rows[order]
    sums = np.zeros((len(first_rows), values.shape[1]), dtype=np.float64)
    np.add.at(sums, groups, values.astype(np.float64))
    counts = np.bincount(groups, minlength=len(first_rows))[:, None]
    return restricted[first_rows], (sums / np.maximum(counts, 1)).astype(values.dtype), target_of[kept]


def _check_fallback(
    keys: np.ndarray, values: np.ndarray, columns: np.ndarray, plan: SegmentPlan, num_actions: int
) -> None:
    """A fallback to compose must be well-formed and keep at least one column in the target."""
    if keys.ndim != 2 or keys.shape[1] != len(columns) or values.shape != (keys.shape[0], num_actions):
        raise TransferError(
            f"source fallback table is malformed: keys {list(keys.shape)}, values {list(values.shape)}, "
            f"projection {list(columns.shape)}"
        )
    if columns.size and (columns.min() < 0 or columns.max() >= plan.source_dim):
        raise TransferError(f"source fallback projection points outside its {plan.source_dim} obs columns")
    if not (plan.source_to_target()[columns] >= 0).any():
        raise TransferError(
            f"source fallback table only reads dropped segment(s) {list(plan.dropped)}: nothing to transfer"
        )


def transfer_tabular_tensors(
    source_tensors: Mapping[str, np.ndarray],
    source_layout: Layout,
    target_layout: Layout,
    *,
    num_actions: int | None = None,
) -> dict[str, np.ndarray]:
    """An empty target table whose fallback is the source table, re-keyed on the target's columns.

    The target's own observations are longer than the source's, so no source key is a target key;
    instead the target looks an unseen observation ``x`` up as ``x[fallback_projection]`` in the
    source's (restricted) table. That is the tabular counterpart of zero input weights: the target
    starts with exactly the source's Q-values, whatever its target-only segments hold.

    A source that is itself a transferred agent is composed when its own table is still empty (its
    fallback is re-mapped). A source with both learned entries and a fallback would need two lookup
    levels, which the single fallback cannot express, so it is refused.
    """
    plan = plan_segment_mapping(source_layout, target_layout)
    for name in ("keys", "values"):
        if name not in source_tensors:
            raise TransferError(f"source has no tabular tensor '{name}': not a tabular checkpoint?")
    keys = np.asarray(source_tensors["keys"])
    values = np.asarray(source_tensors["values"])
    if keys.ndim != 2 or keys.shape[1] != plan.source_dim:
        raise TransferError(
            f"source table keys have shape {list(keys.shape)} but its obs layout has {plan.source_dim} values"
        )
    if values.ndim != 2 or values.shape[0] != keys.shape[0]:
        raise TransferError(f"source table values have shape {list(values.shape)}, keys {list(keys.shape)}")
    if num_actions is not None and values.shape[1] != num_actions:
        raise TransferError(f"number of actions differs: source {values.shape[1]}, target {num_actions}")

    fallback_names = ("fallback_keys", "fallback_values", "fallback_projection")
    present = [name for name in fallback_names if name in source_tensors]
    if present and len(present) != len(fallback_names):
        raise TransferError(f"source fallback table is incomplete: has only {present}")
    has_fallback = bool(present) and source_tensors["fallback_keys"].shape[0] > 0
    if has_fallback and keys.shape[0] > 0:
        raise TransferError(
            f"chained tabular transfer not supported: the source has {keys.shape[0]} learned entries and a "
            f"{source_tensors['fallback_keys'].shape[0]}-entry fallback from an earlier transfer; "
            "transfer from that earlier source instead"
        )
    _warn_dropped(plan)

    if has_fallback:
        table = (
            np.asarray(source_tensors["fallback_keys"]),
            np.asarray(source_tensors["fallback_values"]),
            np.asarray(source_tensors["fallback_projection"]).astype(np.int64),
        )
        _check_fallback(*table, plan, values.shape[1])
    else:
        table = (keys, values, np.arange(plan.source_dim, dtype=np.int64))
    fallback_keys, fallback_values, projection = _project_table(*table, plan)
    return {
        "keys": np.zeros((0, plan.target_dim), dtype=np.float32),
        "values": np.zeros((0, values.shape[1]), dtype=np.float32),
        "fallback_keys": np.ascontiguousarray(fallback_keys, dtype=np.float32),
        "fallback_values": np.ascontiguousarray(fallback_values, dtype=np.float32),
        "fallback_projection": np.ascontiguousarray(projection),
    }
