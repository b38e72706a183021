"""Dense ids of the treasure hunt's observations: what lets a tabular learner hold its tables as plain
arrays ``[rows, num_ids, A]`` instead of an index of the observations met.

An observation is a function of three small numbers (docs/game.md), which its id packs:

* the agent's **cell** (``position``: one-hot over the n * n cells, or ``coords``
  ``(row, col) / (n - 1)``), ``0..n*n-1``;
* what it **believes of each chest** (full or not): k bits, read from the ``treasures`` segment; without
  it (``include_treasures=False``, the single-agent MDP) from the ``view`` window's chest plane, where
  the chests in sight show their bits and a chest out of sight counts as 0; with neither, no bits;
* in deliberative mode its **assignment** (``assignment``: a one-hot of the chest, or all 0), ``0..k``
  (0: none).

``id = (cell * 2**bits + beliefs) * slots + assignment``, ``slots = k + 1`` in deliberative mode, else 1;
``num_ids = n * n * 2**bits * slots``. The ``view`` segment's obstacle and trap planes are functions of
the cell, its chest plane of the cell and the beliefs: they add nothing to the id, and decoding writes
them from the map. Every observation the game produces is the decoding of its id (tests play episodes
of every mode, encoding and view radius to check it). Encoding checks it too, value for value: a vector
that is no observation of the replica's game gets ``-1``, never another state's id.

A batch of replicas may play different maps of one size and chest count (``replicas.maps``): one code
serves them all, each replica decoding with its own map's window. :func:`observation_code` builds it, or
gives None for games it cannot number (another PettingZoo game, different observation rules).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from dqn_transfer.compiled import kernel
from dqn_transfer.envs import Game
from dqn_transfer.envs.game import TreasureHuntGame

SEGMENTS = ("position", "treasures", "assignment", "view")  # what the code reads; a layout with more has none


def observation_code(games: Sequence[Game]) -> ObservationCode | None:
    """The code of the replicas' ``games`` (one per replica), or None: a game that is not the treasure
    hunt, or games whose observations differ in shape (layout or map size)."""
    if not all(isinstance(game, TreasureHuntGame) for game in games):
        return None
    hunts = [game for game in games if isinstance(game, TreasureHuntGame)]
    first = hunts[0]
    if any(name not in SEGMENTS for name, _ in first.obs_layout()):
        return None
    if any(game.obs_layout() != first.obs_layout() or game.size != first.size for game in hunts):
        return None
    return ObservationCode(hunts)


def _view_planes(game: TreasureHuntGame) -> tuple[np.ndarray, np.ndarray]:
    """The ``view`` window of every cell, row-major: ``static [cells, 2 W]`` float32 (blocked: an
    obstacle or off the map; a trap) and ``chest [cells, W]`` (the chest on each window cell, k: none)."""
    n, r, k = game.size, game.view_radius, game.num_treasures
    cells = n * n
    obstacle = np.zeros((n, n), dtype=bool)
    trap = np.zeros((n, n), dtype=bool)
    chest = np.full((n, n), k, dtype=np.int64)
    for cell in game.map.obstacles:
        obstacle[cell] = True
    for cell in game.map.traps:
        trap[cell] = True
    for number, cell in enumerate(game.map.chests):
        chest[cell] = number
    rows, cols = np.divmod(np.arange(cells), n)
    span = np.arange(-r, r + 1)
    window_rows = (rows[:, None, None] + span[None, :, None]).repeat(len(span), axis=2).reshape(cells, -1)
    window_cols = (cols[:, None, None] + span[None, None, :]).repeat(len(span), axis=1).reshape(cells, -1)
    inside = (window_rows >= 0) & (window_rows < n) & (window_cols >= 0) & (window_cols < n)
    at = np.clip(window_rows, 0, n - 1), np.clip(window_cols, 0, n - 1)
    blocked = ~inside | obstacle[at]
    static = np.concatenate([blocked, inside & trap[at]], axis=1).astype(np.float32)
    return static, np.where(inside, chest[at], k)


class ObservationCode:
    """The bijection between R replicas' observations and ``0..num_ids-1`` (see the module docstring)."""

    def __init__(self, games: Sequence[TreasureHuntGame]) -> None:
        """
        :param games: one game per replica, all with one observation layout and map size
        """
        first = games[0]
        offsets, start = {}, 0
        for name, width in first.obs_layout():
            offsets[name] = start
            start += width
        self.obs_dim = start
        k = first.num_treasures
        self.slots = k + 1 if "assignment" in offsets else 1
        self.bits = k if "treasures" in offsets or "view" in offsets else 0
        self.num_ids = first.size**2 * 2**self.bits * self.slots
        self._size, self._chests = first.size, k
        self._position_codes = np.ascontiguousarray(first.position_codes(), dtype=np.float32)
        self._onehot = self._position_codes.shape[1] == first.size**2
        self._offsets = np.array([offsets.get(name, -1) for name in SEGMENTS[1:]], dtype=np.int64)
        # Each replica's map (as an index into the distinct maps' view windows).
        layouts = [game.map.layout for game in games]
        distinct = list(dict.fromkeys(layouts))
        self.replica_map = np.array([distinct.index(layout) for layout in layouts], dtype=np.int64)
        if "view" in offsets:
            windows = [_view_planes(games[layouts.index(layout)]) for layout in distinct]
            self._view_static = np.stack([static for static, _ in windows])
            self._view_chest = np.stack([chest for _, chest in windows])
        else:  # read by no kernel, but typed as when there is a view
            self._view_static = np.zeros((len(distinct), first.size**2, 0), dtype=np.float32)
            self._view_chest = np.zeros((len(distinct), first.size**2, 0), dtype=np.int64)

    def encode(self, obs: np.ndarray, replicas: np.ndarray) -> np.ndarray:
        """``int64 [N]``: the id of each observation ``obs [N, D]`` of replica ``replicas[n]``'s game,
        ``-1`` for a vector that is no observation of it."""
        obs = np.ascontiguousarray(obs, dtype=np.float32)
        maps = self.replica_map[np.asarray(replicas, dtype=np.int64)]
        return encode_rows(obs, maps, *self.kernel_arguments())

    def decode(self, replica: int, ids: np.ndarray) -> np.ndarray:
        """``float32 [N, D]``: the observations of replica ``replica``'s game whose ids are ``ids [N]``."""
        ids = np.asarray(ids, dtype=np.int64)
        out = np.empty((len(ids), self.obs_dim), dtype=np.float32)
        _decode(ids, int(self.replica_map[replica]), out, self._tables())
        return out

    def kernel_arguments(self) -> tuple:
        """What :func:`encode_rows` takes after the observations and their maps."""
        return (self._size, self._onehot, *self._tables())

    def _tables(self) -> tuple:
        """What the kernels read to write an observation."""
        return (
            self._chests,
            self.bits,
            self.slots,
            self._offsets,
            self._position_codes,
            self._view_static,
            self._view_chest,
        )


@kernel
def _write_observation(state: int, map_index: int, out: np.ndarray, tables: tuple) -> None:
    """Write the observation of id ``state`` on map ``map_index`` into ``out [D]`` (every value);
    ``tables``: :meth:`ObservationCode._tables`."""
    k, bits, slots, offsets, position_codes, view_static, view_chest = tables
    assignment = state % slots
    beliefs = (state // slots) % (1 << bits)
    cell = state // slots // (1 << bits)
    out[: position_codes.shape[1]] = position_codes[cell]
    treasures, assigned, view = offsets[0], offsets[1], offsets[2]
    if treasures >= 0:
        for chest in range(k):
            out[treasures + chest] = (beliefs >> chest) & 1
    if assigned >= 0:
        for chest in range(k):
            out[assigned + chest] = chest + 1 == assignment
    if view >= 0:
        static = view_static.shape[2]
        out[view : view + static] = view_static[map_index, cell]
        for w in range(view_chest.shape[2]):
            chest = view_chest[map_index, cell, w]
            out[view + static + w] = (beliefs >> chest) & 1 if chest < k else 0


@kernel
def encode_rows(
    obs: np.ndarray,
    maps: np.ndarray,
    size: int,
    onehot: bool,
    k: int,
    bits: int,
    slots: int,
    offsets: np.ndarray,
    position_codes: np.ndarray,
    view_static: np.ndarray,
    view_chest: np.ndarray,
) -> np.ndarray:
    """:meth:`ObservationCode.encode`: each row's id from its segments, kept if the row is its decoding."""
    ids = np.full(len(obs), -1, dtype=np.int64)
    decoded = np.empty(obs.shape[1], dtype=np.float32)
    treasures, assigned, view = offsets[0], offsets[1], offsets[2]
    for n in range(len(obs)):
        row = obs[n]
        if onehot:
            cell = -1
            for c in range(size * size):
                if row[c] > 0.5:
                    cell = c
                    break
        else:
            r = math.floor(row[0] * (size - 1) + 0.5)
            c = math.floor(row[1] * (size - 1) + 0.5)
            cell = r * size + c if 0 <= r < size and 0 <= c < size else -1
        if cell < 0:
            continue
        beliefs = 0
        if treasures >= 0:
            for chest in range(k):
                if row[treasures + chest] > 0.5:
                    beliefs |= 1 << chest
        elif view >= 0:  # the chests in sight, from the window's chest plane
            static = view_static.shape[2]
            for w in range(view_chest.shape[2]):
                chest = view_chest[maps[n], cell, w]
                if chest < k and row[view + static + w] > 0.5:
                    beliefs |= 1 << chest
        assignment = 0
        if assigned >= 0:
            for chest in range(k):
                if row[assigned + chest] > 0.5:
                    assignment = chest + 1
                    break
        state = (cell * (1 << bits) + beliefs) * slots + assignment
        _write_observation(state, maps[n], decoded, (k, bits, slots, offsets, position_codes, view_static, view_chest))
        differ = 0
        for d in range(len(row)):
            differ += decoded[d] != row[d]
        if differ == 0:
            ids[n] = state
    return ids


@kernel
def _decode(ids: np.ndarray, map_index: int, out: np.ndarray, tables: tuple) -> None:
    """:meth:`ObservationCode.decode` into ``out [N, D]``."""
    for n in range(len(ids)):
        _write_observation(ids[n], map_index, out[n], tables)
