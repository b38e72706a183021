"""Uniform experience replay for many agents in one ``[rows, capacity, width]`` storage.

Each row is one agent (of one replica): its own ring, write pointer and fill level. A dead agent
adds nothing while its teammates keep playing, so rows fill at different rates. Sampling draws every
row's batch from its own filled range only, with its replica's random generator, in one gather, giving
``[rows, B, ...]`` arrays for the batched networks. The storage is numpy on the host, as in SB3: an
engine on another device moves each sampled batch there.

A transition is stored as one float32 vector ``[obs, next_obs, reward, action, terminated]`` (actions
are small integers and ``terminated`` is 0 or 1, both exact in float32), so a sample is one gather.

**Joint replay** (``joint=True``, for ``agent.mixer=vdn``): the team's steps stay aligned. Every step of a
replica stores all K of its rows, each with a ``live`` column (1 where the agent acted; a done agent's row
holds its last observation, action 0, reward 0 and ``live`` 0), so a replica's rows fill alike, and
:meth:`ReplayBuffer.sample_joint` draws the same slots for all of them: B joint steps of the team.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from dqn_transfer.agents.base import Transition


class ReplayBatch(NamedTuple):
    """``batch_size`` transitions per row, each field ``[rows, B, ...]``."""

    obs: np.ndarray  # float32 [rows, B, D]
    actions: np.ndarray  # int64 [rows, B]
    rewards: np.ndarray  # float32 [rows, B]
    next_obs: np.ndarray  # float32 [rows, B, D]
    terminated: np.ndarray  # float32 [rows, B], 1.0 where the episode ended for the agent


# The fields of a checkpoint's replay state, as they are stored there (a joint replay's also ``live``).
FIELD_DTYPES = {
    "obs": np.float32,
    "actions": np.int64,
    "rewards": np.float32,
    "next_obs": np.float32,
    "terminated": np.bool_,
}
JOINT_FIELD_DTYPES = {**FIELD_DTYPES, "live": np.bool_}


class ReplayBuffer:
    """Per-row ring buffers; ``ptr[k]`` is row k's next write slot, ``size[k]`` its fill level.

    :param num_rows: the agents, of all replicas (replica r owns rows ``r * K .. r * K + K - 1``)
    :param capacity: transitions kept per row
    :param obs_dim: values per observation
    :param rngs: one generator per replica, drawing its rows' sample indices
    :param joint: keep each replica's rows aligned step by step, with a ``live`` column (see the module docstring)

    The timeout rule lives here: only ``terminated`` is stored. A step truncated by the time limit
    is, for the TD target, an ordinary step whose next state still has a future (SB3's
    ``handle_timeout_termination``), so nothing downstream needs to know it was the last one.
    """

    def __init__(
        self,
        num_rows: int,
        capacity: int,
        obs_dim: int,
        rngs: Sequence[np.random.Generator],
        joint: bool = False,
    ) -> None:
        if num_rows % len(rngs):
            raise ValueError(f"{len(rngs)} generators cannot split {num_rows} replay rows evenly")
        self.num_rows = num_rows
        self.capacity = capacity
        self.obs_dim = obs_dim
        self.rngs = list(rngs)
        self.rows_per_rng = num_rows // len(self.rngs)
        self.joint = joint
        self.fields = JOINT_FIELD_DTYPES if joint else FIELD_DTYPES
        d = obs_dim
        self.columns: dict[str, slice | int] = {
            "obs": slice(0, d),
            "next_obs": slice(d, 2 * d),
            "rewards": 2 * d,
            "actions": 2 * d + 1,
            "terminated": 2 * d + 2,
        }
        if joint:
            self.columns["live"] = 2 * d + 3
        # numpy's zeros come from calloc: pages are committed as they are first written, so a
        # 50k-transition buffer of 64 replicas costs what it holds, not 11 GB up front.
        self.storage = np.zeros((num_rows, capacity, 2 * d + 3 + int(joint)), dtype=np.float32)
        self.ptr = np.zeros(num_rows, dtype=np.int64)
        self.size = np.zeros(num_rows, dtype=np.int64)

    def _pack(self, obs, actions, rewards, next_obs, terminated, live=None) -> np.ndarray:
        """``[N, width]`` storage rows of N transitions (``live``: a joint replay's column)."""
        obs = np.asarray(obs).reshape(-1, self.obs_dim)
        packed = np.empty((len(obs), self.storage.shape[-1]), dtype=np.float32)
        c = self.columns
        packed[:, c["obs"]] = obs
        packed[:, c["next_obs"]] = np.asarray(next_obs).reshape(-1, self.obs_dim)
        packed[:, c["rewards"]] = np.asarray(rewards).reshape(-1)
        packed[:, c["actions"]] = np.asarray(actions).reshape(-1)
        packed[:, c["terminated"]] = np.asarray(terminated).reshape(-1)
        if self.joint:
            packed[:, c["live"]] = np.asarray(live).reshape(-1)
        return packed

    def add(self, transition: Transition) -> None:
        """Store row k of the joint step in row k's buffer, for the rows live in it (a joint replay: for
        every row of a replica with a live agent)."""
        stored = transition.live
        if self.joint:
            stored = np.repeat(stored.reshape(-1, self.rows_per_rng).any(axis=1), self.rows_per_rng)
        rows = np.flatnonzero(stored)
        if rows.size == 0:
            return
        t = transition
        if rows.size < self.num_rows:
            t = Transition(*(field[rows] for field in t))
        ptr = self.ptr[rows]
        self.storage[rows, ptr] = self._pack(t.obs, t.actions, t.rewards, t.next_obs, t.terminated, t.live)
        self.ptr[rows] = (ptr + 1) % self.capacity
        self.size[rows] = np.minimum(self.size[rows] + 1, self.capacity)

    def extend(
        self,
        row: int,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """Append N transitions (``[N, ...]`` arrays, oldest first) to one row's buffer.

        This is how experience crosses agents (``transfer.exchange=shared_replay``): an agent's row
        can receive a teammate's transitions. Beyond ``capacity`` only the newest ones are kept.
        """
        self._check_per_row("extend one row")
        packed = self._pack(obs, actions, rewards, next_obs, terminated)[-self.capacity :]
        n = len(packed)
        if n == 0:
            return
        cols = (self.ptr[row] + np.arange(n)) % self.capacity
        self.storage[row, cols] = packed
        self.ptr[row] = (self.ptr[row] + n) % self.capacity
        self.size[row] = min(self.size[row] + n, self.capacity)

    def sample(self, batch_size: int) -> ReplayBatch:
        """``batch_size`` transitions per row, uniformly (with replacement) from its filled range.

        An empty row (``size[k] == 0``) gets placeholder transitions (slot 0) that its loss must ignore.
        """
        high = np.maximum(self.size, 1)[:, None]
        k = self.rows_per_rng
        cols = np.concatenate(
            [rng.integers(0, high[r * k : (r + 1) * k], size=(k, batch_size)) for r, rng in enumerate(self.rngs)]
        )
        return self._batch(self._pick(np.arange(self.num_rows)[:, None], cols))

    def sample_rows(self, sources: np.ndarray) -> ReplayBatch:
        """``sources [rows, B]``: sample b of row i is drawn uniformly (with replacement) from the filled
        range of row ``sources[i, b]`` (a row of the same replica: each replica's generator draws its
        rows' samples). ``transfer.exchange=experience`` draws an agent's batch from its team-mates' rows
        this way (:mod:`~dqn_transfer.agents.shared_experience`). An empty source row gives placeholders
        (slot 0), whose weight in the loss must be 0."""
        self._check_per_row("sample rows from other rows")
        high = np.maximum(self.size, 1)[sources]
        k = self.rows_per_rng
        cols = np.concatenate([rng.integers(0, high[r * k : (r + 1) * k]) for r, rng in enumerate(self.rngs)])
        return self._batch(self._pick(sources, cols))

    def sample_joint(self, batch_size: int) -> tuple[ReplayBatch, np.ndarray]:
        """A joint replay's ``batch_size`` joint steps per replica, uniformly (with replacement) from its
        filled range, the same slots for all its rows; and ``live`` ``float32 [rows, B]``. An empty
        replica gets placeholders (slot 0) that its loss must ignore."""
        k = self.rows_per_rng
        high = np.maximum(self.size[::k], 1)
        cols = np.repeat(np.stack([rng.integers(0, high[r], size=batch_size) for r, rng in enumerate(self.rngs)]), k, 0)
        picked = self._pick(np.arange(self.num_rows)[:, None], cols)
        return self._batch(picked), picked[..., self.columns["live"]]

    def _check_per_row(self, what: str) -> None:
        if self.joint:
            raise ValueError(f"a joint replay (agent.mixer=vdn) keeps the team's steps aligned: it cannot {what}")

    def _pick(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The stored vectors at slots ``cols [rows, B]`` of rows ``rows`` (broadcast against ``cols``)."""
        # One flat gather (row k, slot c is element k * capacity + c of the [rows * capacity, width] view).
        flat = (rows * self.capacity + cols).reshape(-1)
        return self.storage.reshape(-1, self.storage.shape[-1])[flat].reshape(*cols.shape, -1)

    def _batch(self, picked: np.ndarray) -> ReplayBatch:
        """Stored vectors ``[rows, B, width]`` as a batch."""
        c = self.columns
        return ReplayBatch(
            picked[..., c["obs"]],
            picked[..., c["actions"]].astype(np.int64),
            picked[..., c["rewards"]],
            picked[..., c["next_obs"]],
            picked[..., c["terminated"]],
        )

    # ------------------------------------------------------------------------ checkpoints
    def state_dict(self, rows: slice | None = None) -> dict[str, np.ndarray]:
        """Pointers and the filled part of the storage of ``rows`` (default all), by field, as numpy arrays."""
        rows = slice(None) if rows is None else rows
        size = self.size[rows]
        filled = int(size.max(initial=0))
        stored = self.storage[rows, :filled]
        # Contiguous copies: safetensors writes an array's raw buffer, and a slice is only a view.
        arrays: dict[str, np.ndarray] = {
            name: np.ascontiguousarray(stored[..., self.columns[name]].astype(dtype))
            for name, dtype in self.fields.items()
        }
        arrays["ptr"] = self.ptr[rows].copy()
        arrays["size"] = size.copy()
        return arrays

    def load_state_dict(self, arrays: dict[str, np.ndarray], rows: slice | None = None) -> None:
        """Load what :meth:`state_dict` gave into ``rows`` (default all); checked before anything is written."""
        rows = slice(None) if rows is None else rows
        num_rows = len(range(self.num_rows)[rows])
        size = np.asarray(arrays["size"], dtype=np.int64)
        if size.shape != (num_rows,) or (size > self.capacity).any():
            raise ValueError(
                f"replay state holds sizes {size.tolist()}, not valid for {num_rows} agents "
                f"with capacity {self.capacity}"
            )
        filled = int(size.max(initial=0))
        for name in self.fields:
            expected = (num_rows, filled, self.obs_dim) if name in ("obs", "next_obs") else (num_rows, filled)
            if tuple(np.shape(arrays[name])) != expected:
                raise ValueError(
                    f"replay array '{name}' has shape {list(np.shape(arrays[name]))}, expected {list(expected)}"
                )
        packed = self._pack(*(np.asarray(arrays[name]) for name in self.fields))
        self.storage[rows] = 0.0
        self.storage[rows, :filled] = packed.reshape(num_rows, filled, -1)
        self.ptr[rows] = np.asarray(arrays["ptr"], dtype=np.int64)
        self.size[rows] = size
