"""Map a pretrained agent's tensors onto a target agent whose observation or map differs.

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
- ``agent_id`` (a shared network's one-hot of the agent's index, ``agent.agent_id_input``) may change
  size with the team: column k is agent k's on both sides, so agent k < min(K_source, K_target) keeps
  its columns, a new agent's column gets zero weights (it reads no index) and a source-only agent's is
  dropped.

The maps may differ too (an :class:`Embedding`): the source map is placed at ``offset`` inside a target
map at least as large. A source cell maps to its shifted target cell, and a source chest to the target
chest on its shifted cell (the chest segments have one column per chest); new target chests get zero
input weights, and source chests with no chest on their shifted cell are dropped with a warning naming
them. Target cells outside the embedded region read nothing (``fill=zero``) or the nearest embedded
cell (``fill=nearest``). Without an embedding the maps are taken to be the same, and a shared segment
of a different size (another map size, chest count or view radius) raises :class:`TransferError`, as
do a different hidden shape or number of actions.

All of this is one affine change of the input (:func:`input_map`): on every *embedded* state (an agent
on an embedded cell, the matched chests as the source saw them, whatever it believes of new chests),
the source's observation is ``M x + c`` for the target's observation ``x``. A network's first layer
becomes ``W M``, its bias ``b + W c``, so it computes the source's Q-values there. A table is re-keyed
state by state instead (its keys are looked up by their exact bytes).

Tensor names follow the learners: DQN ``q.layers.{l}.weight`` ``[out, in]`` / ``q.layers.{l}.bias``
``[out]`` and the same under ``target.``; tabular ``keys`` ``[N, D]`` / ``values`` ``[N, A]`` plus
optional fallback tables consulted in turn for an unseen observation ``x``
(:func:`~dqn_transfer.agents.tabular.fallback_names`:
``fallback_keys`` ``[M, Ds]``, ``fallback_values`` ``[M, A]``, ``fallback_projection`` ``[Ds]`` int64,
looked up as ``x[fallback_projection]``; then ``fallback1_*``, ...).

This module is pure tensor bookkeeping: the orchestration (finding or pretraining the source,
caching) lives in :mod:`dqn_transfer.sources.resolve` and :mod:`dqn_transfer.transfer.warm_start`.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from dqn_transfer.agents.agent_id import AGENT_ID
from dqn_transfer.agents.tabular import fallback_names, fallback_tables

Layout = Sequence[tuple[str, int]]
Cell = tuple[int, int]

# Segments with one column per chest, in the map's row-major chest order.
CHEST_SEGMENTS = ("treasures", "assignment")
# Likely cause of a size mismatch, per segment the env produces; shown to the user with the error.
_SIZE_MISMATCH_HINTS = {
    "position": "different map size or obs_encoding?",
    "treasures": "different number of treasures?",
    "assignment": "different number of treasures?",
    "view": "different view_radius?",
}
_LAYER_WEIGHT = re.compile(r"^q\.layers\.(\d+)\.weight$")
FILLS = ("zero", "nearest")


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


# ------------------------------------------------------------------------------------------ maps


def _cell_name(cell: Cell) -> str:
    return f"row {cell[0]}, col {cell[1]}"


@dataclass(frozen=True)
class MapGeometry:
    """What the mapping reads of a map: its side, its chests, and the ``position`` segment of each cell."""

    size: int
    chests: tuple[Cell, ...]  # row-major: the order of the chest segments' columns
    encoding: str  # the game's obs_encoding: "onehot" or "coords"
    position_codes: np.ndarray  # [size * size, width]: the `position` segment of each cell (row-major)


@dataclass(frozen=True)
class Embedding:
    """The source map placed at ``offset`` (row, col) inside the target map; ``fill`` says what target
    cells outside it read. Refuses a source that does not fit."""

    source: MapGeometry
    target: MapGeometry
    offset: tuple[int, int] = (0, 0)
    fill: str = "zero"

    def __post_init__(self) -> None:
        ns, nt = self.source.size, self.target.size
        if ns > nt:
            raise TransferError(
                f"the source's {ns}x{ns} map does not fit in this run's {nt}x{nt} map "
                "(a target map must be at least as large as its source)"
            )
        row, col = self.offset
        if not (0 <= row <= nt - ns and 0 <= col <= nt - ns):
            raise TransferError(
                f"transfer.offset=[{row}, {col}] puts the source's {ns}x{ns} map off this run's "
                f"{nt}x{nt} map (each offset must be in 0..{nt - ns})"
            )
        if self.source.encoding != self.target.encoding:
            raise TransferError(f"obs_encoding differs: source {self.source.encoding}, target {self.target.encoding}")
        if self.fill not in FILLS:
            raise TransferError(f"transfer.fill must be one of {list(FILLS)}, got {self.fill!r}")

    def source_cells(self) -> np.ndarray:
        """The source cell (row-major index) each target cell reads: its shifted cell inside the embedded
        region; outside it -1 (``fill=zero``) or the nearest embedded cell (``fill=nearest``)."""
        ns, nt = self.source.size, self.target.size
        rows, cols = np.divmod(np.arange(nt * nt), nt)
        rows, cols = rows - self.offset[0], cols - self.offset[1]
        if self.fill == "nearest":  # the nearest cell of a square: clamp each coordinate into it
            return np.clip(rows, 0, ns - 1) * ns + np.clip(cols, 0, ns - 1)
        inside = (rows >= 0) & (rows < ns) & (cols >= 0) & (cols < ns)
        return np.where(inside, rows * ns + cols, -1)

    def chest_targets(self) -> np.ndarray:
        """The target chest of each source chest (the one on its shifted cell), -1 where there is none."""
        index = {cell: j for j, cell in enumerate(self.target.chests)}
        row, col = self.offset
        return np.array([index.get((r + row, c + col), -1) for r, c in self.source.chests], dtype=np.int64)

    def dropped_chests(self) -> list[Cell]:
        """Source chests with no target chest on their shifted cell."""
        return [cell for cell, j in zip(self.source.chests, self.chest_targets()) if j < 0]


# -------------------------------------------------------------------------------------- segments


@dataclass(frozen=True)
class SharedSegment:
    """A segment present in both layouts, with its column range on each side."""

    name: str
    source: slice
    target: slice


@dataclass(frozen=True)
class SegmentPlan:
    """Which source segments map onto which target segments (``shared`` is in source order)."""

    source_dim: int
    target_dim: int
    shared: tuple[SharedSegment, ...]
    target_only: tuple[str, ...]
    dropped: tuple[str, ...]


def _resized_by(embedding: Embedding | None, name: str) -> bool:
    """Whether segment ``name`` may differ in size: ``agent_id`` (another team size), and with an
    ``embedding`` the cells and chests it maps."""
    return name == AGENT_ID or (embedding is not None and (name == "position" or name in CHEST_SEGMENTS))


def _index_pairs(seg: SharedSegment) -> tuple[np.ndarray, np.ndarray]:
    """Source and target columns of a segment copied column by column: the first ``min`` of the two
    sizes (the same size but for ``agent_id``, whose column k is agent k's on both sides; a new agent's
    column reads nothing, a source-only agent's is dropped)."""
    n = min(seg.source.stop - seg.source.start, seg.target.stop - seg.target.start)
    return seg.source.start + np.arange(n), seg.target.start + np.arange(n)


def _check_against_maps(layout: list[tuple[str, int]], geometry: MapGeometry, which: str) -> None:
    """A layout must describe its map: a ``position`` of its encoding, one chest column per chest."""
    expected = {"position": geometry.position_codes.shape[1], **{name: len(geometry.chests) for name in CHEST_SEGMENTS}}
    for name, size in layout:
        if name in expected and size != expected[name]:
            raise TransferError(
                f"the {which} obs layout has {name}:{size}, but its {geometry.size}x{geometry.size} "
                f"map with {len(geometry.chests)} chest(s) gives {name}:{expected[name]}"
            )


def plan_segment_mapping(
    source_layout: Layout, target_layout: Layout, embedding: Embedding | None = None
) -> SegmentPlan:
    """Match segments by name; refuse a shared segment whose size differs unless ``embedding`` maps it."""
    source = _normalise_layout(source_layout, "source")
    target = _normalise_layout(target_layout, "target")
    if embedding is not None:
        _check_against_maps(source, embedding.source, "source")
        _check_against_maps(target, embedding.target, "target")
    source_slices, target_slices = segment_slices(source), segment_slices(target)
    target_sizes = dict(target)
    shared = []
    for name, size in source:
        if name not in target_sizes:
            continue
        if target_sizes[name] != size and not _resized_by(embedding, name):
            hint = _SIZE_MISMATCH_HINTS.get(name)
            raise TransferError(
                f"segment '{name}' has {size} values in the source and {target_sizes[name]} in the target"
                + (f" ({hint})" if hint else "")
            )
        shared.append(SharedSegment(name, source_slices[name], target_slices[name]))
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


def _warn_dropped(plan: SegmentPlan, embedding: Embedding | None) -> None:
    if plan.dropped:
        warnings.warn(
            f"transfer drops source-only obs segment(s) {list(plan.dropped)}: the target has no such input",
            stacklevel=3,
        )
    chest_segments = [seg.name for seg in plan.shared if seg.name in CHEST_SEGMENTS]
    if embedding is not None and chest_segments and embedding.dropped_chests():
        cells = "; ".join(_cell_name(cell) for cell in embedding.dropped_chests())
        warnings.warn(
            f"transfer drops the source's chest(s) at {cells}: no target chest at offset "
            f"{list(embedding.offset)} from them (their {'/'.join(chest_segments)} inputs read as 0)",
            stacklevel=3,
        )


def input_map(plan: SegmentPlan, embedding: Embedding | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(M [Ds, Dt], c [Ds])``, float64, such that the source observation of an embedded state is
    ``M @ x + c`` for its target observation ``x``. Each column of ``M`` holds at most one non-zero,
    so ``W @ M`` copies (or, for ``coords``, scales) weights exactly."""
    matrix = np.zeros((plan.source_dim, plan.target_dim))
    shift = np.zeros(plan.source_dim)
    for seg in plan.shared:
        s, t = seg.source.start, seg.target.start
        if embedding is not None and seg.name == "position":
            _position_map(embedding, matrix, shift, s, t)
        elif embedding is not None and seg.name in CHEST_SEGMENTS:
            chests = embedding.chest_targets()
            kept = np.flatnonzero(chests >= 0)
            matrix[s + kept, t + chests[kept]] = 1.0
        else:
            matrix[_index_pairs(seg)] = 1.0
    return matrix, shift


def _position_map(embedding: Embedding, matrix: np.ndarray, shift: np.ndarray, s: int, t: int) -> None:
    """The ``position`` block of :func:`input_map`: a cell selection (onehot) or an affine map (coords)."""
    ns, nt = embedding.source.size, embedding.target.size
    if embedding.source.encoding == "onehot":
        cells = embedding.source_cells()
        read = np.flatnonzero(cells >= 0)
        matrix[s + cells[read], t + read] = 1.0
        return
    if embedding.fill != "zero":
        raise TransferError(
            "transfer.fill=nearest needs obs_encoding=onehot: a network's coords input maps "
            "every cell by one affine transform"
        )
    # coords: source r / (ns - 1) with r = R - offset, for target R / (nt - 1).
    for axis in (0, 1):
        matrix[s + axis, t + axis] = (nt - 1) / (ns - 1)
        shift[s + axis] = -embedding.offset[axis] / (ns - 1)


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
    embedding: Embedding | None = None,
) -> dict[str, np.ndarray]:
    """Target-shaped ``q.*`` and ``target.*`` tensors computing the source's Q-function.

    Only the first layer sees the observation, so only it changes: weight ``W M`` and bias ``b + W c``
    (:func:`input_map`). Target-only segments and new chests keep zero weights, so on every embedded
    state the network returns the source's Q-values (exactly when the maps have the same size and no
    segment is dropped; to float rounding for a resized ``coords`` input). Deeper layers are copied.
    The target network is a copy of the transferred online network (not of the source's target), as
    after a hard update.
    """
    plan = plan_segment_mapping(source_layout, target_layout, embedding)
    layers = _dqn_layers(source_tensors)
    source_in = layers[0][0].shape[1]
    if source_in != plan.source_dim:
        raise TransferError(f"source network takes {source_in} inputs but its obs layout has {plan.source_dim} values")
    source_hidden = [weight.shape[0] for weight, _ in layers[:-1]]
    if source_hidden != list(target_hidden):
        raise TransferError(f"hidden layers differ: source {source_hidden}, target {list(target_hidden)}")
    source_actions = layers[-1][0].shape[0]
    if source_actions != num_actions:
        raise TransferError(f"number of actions differs: source {source_actions}, target {num_actions}")
    _warn_dropped(plan, embedding)
    matrix, shift = input_map(plan, embedding)
    weight, bias = (np.asarray(tensor) for tensor in layers[0])
    first = (
        (weight.astype(np.float64) @ matrix).astype(weight.dtype),
        (bias.astype(np.float64) + weight.astype(np.float64) @ shift).astype(bias.dtype),
    )

    out: dict[str, np.ndarray] = {}
    for l, (weight, bias) in enumerate([first, *layers[1:]]):
        for net in ("q", "target"):
            # Separate contiguous copies: the learner may keep what it is given.
            out[f"{net}.layers.{l}.weight"] = np.array(weight, order="C")
            out[f"{net}.layers.{l}.bias"] = np.array(bias, order="C")
    return out


def map_input_moments(
    plan: SegmentPlan, embedding: Embedding | None, exp_avg: np.ndarray, exp_avg_sq: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Adam's moments of a first-layer weight stored ``[in, out]``, mapped like the weight: the gradient
    of ``W M`` is the source's gradient times ``M``, and its square times ``M * M``."""
    matrix, _ = input_map(plan, embedding)
    return (
        (matrix.T @ exp_avg.astype(np.float64)).astype(exp_avg.dtype),
        ((matrix * matrix).T @ exp_avg_sq.astype(np.float64)).astype(exp_avg_sq.dtype),
    )


# ----------------------------------------------------------------------------------------- tabular


def _merge_duplicates(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows whose keys are byte-identical (the equality the tabular learner uses) become one, with the
    mean of their values, in first-occurrence order. Keys collide when a dropped segment or chest was
    all that told them apart: the mean estimates the value across the contexts the source saw, where
    the max would carry the optimistic bias of the luckiest one."""
    keys = np.ascontiguousarray(keys)
    rows = keys.view(np.dtype((np.void, keys.dtype.itemsize * keys.shape[1]))).ravel()
    _, first_rows, inverse = np.unique(rows, return_index=True, return_inverse=True)
    order = np.argsort(first_rows)  # unique() sorts by bytes; restore first-occurrence order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    groups, first_rows = rank[inverse.ravel()], first_rows[order]
    sums = np.zeros((len(first_rows), values.shape[1]), dtype=np.float64)
    np.add.at(sums, groups, values.astype(np.float64))
    counts = np.bincount(groups, minlength=len(first_rows))[:, None]
    return keys[first_rows], (sums / np.maximum(counts, 1)).astype(values.dtype)


def _column_targets(plan: SegmentPlan, embedding: Embedding | None) -> np.ndarray:
    """The target column of each source column, -1 where it has none (a dropped segment or chest).
    With an embedding, ``position`` columns are -1 too: a table maps positions cell by cell."""
    targets = np.full(plan.source_dim, -1, dtype=np.int64)
    for seg in plan.shared:
        if embedding is not None and seg.name == "position":
            continue
        if embedding is not None and seg.name in CHEST_SEGMENTS:
            chests = embedding.chest_targets()
            targets[seg.source] = np.where(chests >= 0, seg.target.start + chests, -1)
        else:
            source_columns, target_columns = _index_pairs(seg)
            targets[source_columns] = target_columns
    return targets


def _rekey_positions(
    keys: np.ndarray, columns: np.ndarray, plan: SegmentPlan, embedding: Embedding | None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Each key's rows in the target, by position: ``(source row of each new row, their target position
    codes or None, the target columns of those codes)``. One row per target cell that reads the key's
    source cell (several with ``fill=nearest``); without an embedding, positions are copied as columns."""
    position = next((seg for seg in plan.shared if seg.name == "position"), None)
    if embedding is None or position is None:
        return np.arange(len(keys)), None, np.zeros(0, dtype=np.int64)
    in_position = (columns >= position.source.start) & (columns < position.source.stop)
    if not in_position.any():
        return np.arange(len(keys)), None, np.zeros(0, dtype=np.int64)
    assert embedding is not None and position is not None  # in_position is all False without them
    if in_position.sum() != position.source.stop - position.source.start:
        raise TransferError("source table reads only part of the position segment: cannot map it onto another map")
    codes = np.ascontiguousarray(keys[:, in_position][:, np.argsort(columns[in_position])])
    cell_of = {code.tobytes(): cell for cell, code in enumerate(embedding.source.position_codes.astype(codes.dtype))}
    cells = [cell_of.get(code.tobytes(), -1) for code in codes]
    if -1 in cells:
        raise TransferError(
            f"source table key {codes[cells.index(-1)].tolist()} is not a position of its "
            f"{embedding.source.size}x{embedding.source.size} map"
        )
    readers = embedding.source_cells()
    targets_of = {cell: np.flatnonzero(readers == cell) for cell in set(cells)}
    rows = np.repeat(np.arange(len(keys)), [len(targets_of[cell]) for cell in cells])
    target_cells = np.concatenate([targets_of[cell] for cell in cells]) if cells else np.zeros(0, dtype=np.int64)
    return (
        rows,
        embedding.target.position_codes[target_cells].astype(keys.dtype),
        np.arange(position.target.start, position.target.stop),
    )


def _rekey_table(
    keys: np.ndarray,
    values: np.ndarray,
    columns: np.ndarray,
    plan: SegmentPlan,
    embedding: Embedding | None,
    num_actions: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A table keyed on source ``columns``, re-keyed on target columns: ``(keys, values, projection)``
    with the target column of each key column in ``projection``."""
    if keys.ndim != 2 or keys.shape[1] != len(columns) or values.shape != (keys.shape[0], num_actions):
        raise TransferError(
            f"source table is malformed: keys {list(keys.shape)}, values {list(values.shape)}, "
            f"{len(columns)} key columns, {num_actions} actions"
        )
    if columns.size and (columns.min() < 0 or columns.max() >= plan.source_dim):
        raise TransferError(f"source fallback projection points outside its {plan.source_dim} obs columns")
    rows, position_codes, position_columns = _rekey_positions(keys, columns, plan, embedding)
    targets = _column_targets(plan, embedding)[columns]
    kept = targets >= 0
    if position_codes is None and not kept.any():
        raise TransferError(f"source table only reads dropped segment(s) {list(plan.dropped)}: nothing to transfer")
    new_keys = keys[rows][:, kept]
    projection = targets[kept]
    if position_codes is not None:  # positions first, as in every layout the game makes
        new_keys = np.concatenate([position_codes, new_keys], axis=1)
        projection = np.concatenate([position_columns, projection])
    merged_keys, merged_values = _merge_duplicates(new_keys, values[rows])
    return merged_keys, merged_values, projection


def transfer_tabular_tensors(
    source_tensors: Mapping[str, np.ndarray],
    source_layout: Layout,
    target_layout: Layout,
    *,
    num_actions: int | None = None,
    embedding: Embedding | None = None,
    gate_column: int | None = None,
) -> dict[str, np.ndarray]:
    """An empty target table whose fallbacks are the source's tables, re-keyed on the target's columns.

    The target's own observations differ from the source's, so no source key is a target key;
    instead the target looks an unseen observation ``x`` up as ``x[fallback_projection]`` in the
    source's re-keyed table, then in the next fallback. That is the tabular counterpart of zero input
    weights: on every embedded state the target starts with exactly the source's Q-values, whatever
    its target-only segments and new chests hold. A source that was itself transferred keeps its
    lookup order: its learned table first, then its own fallbacks, each re-keyed.

    ``gate_column``: a target column every key also reads, as 1 (``transfer.chest_aware``: the
    `treasures` entry of the source's chest, 1 while it is full), so the source's values apply only
    while that column reads 1; otherwise no fallback knows the observation and it starts at 0.
    """
    plan = plan_segment_mapping(source_layout, target_layout, embedding)
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
    actions = values.shape[1]
    if num_actions is not None and actions != num_actions:
        raise TransferError(f"number of actions differs: source {actions}, target {num_actions}")
    try:
        fallbacks = fallback_tables(source_tensors)
    except ValueError as err:
        raise TransferError(f"source {err}") from None
    _warn_dropped(plan, embedding)
    if gate_column is not None and not 0 <= gate_column < plan.target_dim:
        raise TransferError(f"gate column {gate_column} is outside the target's {plan.target_dim} obs columns")

    learned = (keys, values, np.arange(plan.source_dim, dtype=np.int64))
    tables = fallbacks if fallbacks and keys.shape[0] == 0 else [learned, *fallbacks]
    out = {"keys": np.zeros((0, plan.target_dim), dtype=np.float32), "values": np.zeros((0, actions), dtype=np.float32)}
    for level, (table_keys, table_values, columns) in enumerate(tables):
        mapped = _rekey_table(table_keys, table_values, columns.astype(np.int64), plan, embedding, actions)
        if gate_column is not None:
            new_keys, new_values, projection = mapped
            gate = np.ones((len(new_keys), 1), dtype=new_keys.dtype)
            mapped = (np.concatenate([new_keys, gate], axis=1), new_values, np.append(projection, gate_column))
        for name, array, dtype in zip(fallback_names(level), mapped, (np.float32, np.float32, np.int64)):
            out[name] = np.ascontiguousarray(array, dtype=dtype)
    return out


def transfer_agent_tensors(
    source_tensors: Mapping[str, np.ndarray],
    source_layout: Layout,
    target_layout: Layout,
    target_hidden: Sequence[int],
    num_actions: int,
    embedding: Embedding | None = None,
    gate_column: int | None = None,
) -> dict[str, np.ndarray]:
    """A source agent's tensors mapped onto the target's observation, by the checkpoint's own format: a
    table's (``keys`` / ``values``: :func:`transfer_tabular_tensors`, with its ``gate_column``) or a
    network's (``q.*``: :func:`transfer_dqn_tensors`, into ``target_hidden`` layers; a network has no
    lookup to gate, so a ``gate_column`` is refused)."""
    if "keys" in source_tensors:
        return transfer_tabular_tensors(
            source_tensors,
            source_layout,
            target_layout,
            num_actions=num_actions,
            embedding=embedding,
            gate_column=gate_column,
        )
    if gate_column is not None:
        raise TransferError("transfer.chest_aware=true gates a table's lookup: this source is a network")
    return transfer_dqn_tensors(source_tensors, source_layout, target_layout, target_hidden, num_actions, embedding)
