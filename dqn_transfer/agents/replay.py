"""Uniform experience replay for K agents in one ``[K, capacity, ...]`` storage.

Each agent has its own row, write pointer and fill level: a dead agent adds nothing while its
teammates keep playing, so rows fill at different rates. Sampling draws every agent's batch from its
own filled range only, in one gather, giving ``[K, B, ...]`` tensors for the batched networks.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from dqn_transfer.agents.base import Transition


class ReplayBatch(NamedTuple):
    """``batch_size`` transitions per agent, each field ``[K, B, ...]``."""

    obs: torch.Tensor  # float32 [K, B, D]
    actions: torch.Tensor  # int64 [K, B]
    rewards: torch.Tensor  # float32 [K, B]
    next_obs: torch.Tensor  # float32 [K, B, D]
    terminated: torch.Tensor  # bool [K, B]


# Stored fields and their dtypes (what the TD target reads); the observation fields hold obs_dim
# values per transition.
_FIELDS = {name: dtype for name, dtype in zip(ReplayBatch._fields, (torch.float32, torch.int64, torch.float32,
                                                                    torch.float32, torch.bool))}
_OBS_FIELDS = ("obs", "next_obs")


def _as_fields(*values: np.ndarray) -> dict[str, np.ndarray]:
    """Name the stored transition arrays in storage order."""
    return {name: np.asarray(value) for name, value in zip(_FIELDS, values)}


class ReplayBuffer:
    """Per-agent ring buffers; ``ptr[k]`` is agent k's next write slot, ``size[k]`` its fill level.

    The timeout rule lives here: only ``terminated`` is stored. A step truncated by the time limit
    is, for the TD target, an ordinary step whose next state still has a future (SB3's
    ``handle_timeout_termination``), so nothing downstream needs to know it was the last one.
    """

    def __init__(
        self,
        num_agents: int,
        capacity: int,
        obs_dim: int,
        rng: np.random.Generator,
        device: torch.device | str = "cpu",
    ) -> None:
        self.num_agents = num_agents
        self.capacity = capacity
        self.obs_dim = obs_dim
        self.rng = rng
        self.device = torch.device(device)
        self.storage = {
            name: torch.zeros(self._shape(name, capacity), dtype=dtype, device=self.device)
            for name, dtype in _FIELDS.items()
        }
        self.ptr = np.zeros(num_agents, dtype=np.int64)
        self.size = np.zeros(num_agents, dtype=np.int64)

    def _shape(self, name: str, length: int) -> tuple[int, ...]:
        extra = (self.obs_dim,) if name in _OBS_FIELDS else ()
        return (self.num_agents, length, *extra)

    def _write(self, rows: np.ndarray, cols: np.ndarray, data: dict[str, np.ndarray]) -> None:
        if self.device.type == "cpu":
            # Through numpy views of the storage (shared memory): a third of the torch indexing cost.
            for name, tensor in self.storage.items():
                tensor.numpy()[rows, cols] = data[name]
            return
        rows_t, cols_t = torch.from_numpy(rows).to(self.device), torch.from_numpy(cols).to(self.device)
        for name, dtype in _FIELDS.items():
            value = torch.as_tensor(np.asarray(data[name]), dtype=dtype, device=self.device)
            self.storage[name][rows_t, cols_t] = value

    def add(self, transition: Transition) -> None:
        """Store row k of the joint step in agent k's buffer, for the agents live in it."""
        rows = np.flatnonzero(transition.live)
        if rows.size == 0:
            return
        t = transition
        data = _as_fields(t.obs, t.actions, t.rewards, t.next_obs, t.terminated)
        self._write(rows, self.ptr[rows], {name: value[rows] for name, value in data.items()})
        self.ptr[rows] = (self.ptr[rows] + 1) % self.capacity
        self.size[rows] = np.minimum(self.size[rows] + 1, self.capacity)

    def extend(
        self,
        agent: int,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """Append N transitions (``[N, ...]`` arrays, oldest first) to one agent's buffer.

        This is how experience crosses agents (``transfer.exchange=shared_replay``): an agent's row
        can receive a teammate's transitions. Beyond ``capacity`` only the newest ones are kept.
        """
        data = _as_fields(obs, actions, rewards, next_obs, terminated)
        data = {name: value[-self.capacity :] for name, value in data.items()}
        n = len(data["actions"])
        if n == 0:
            return
        cols = (self.ptr[agent] + np.arange(n)) % self.capacity
        self._write(np.full(n, agent, dtype=np.int64), cols, data)
        self.ptr[agent] = (self.ptr[agent] + n) % self.capacity
        self.size[agent] = min(self.size[agent] + n, self.capacity)

    def sample(self, batch_size: int) -> ReplayBatch:
        """``batch_size`` transitions per agent, uniformly (with replacement) from its filled range.

        An empty agent (``size[k] == 0``) gets placeholder rows (slot 0) that its loss must ignore.
        """
        high = np.maximum(self.size, 1)[:, None]
        cols = self.rng.integers(0, high, size=(self.num_agents, batch_size))
        # One flat gather per field (row k, slot c is element k * capacity + c of the [K * capacity, ...]
        # view): much cheaper than indexing with a row tensor and a column tensor.
        flat = (np.arange(self.num_agents)[:, None] * self.capacity + cols).reshape(-1)
        flat_t = torch.from_numpy(flat).to(self.device)
        shape = (self.num_agents, batch_size)
        return ReplayBatch(*(tensor.flatten(0, 1).index_select(0, flat_t).unflatten(0, shape)
                             for tensor in self.storage.values()))

    def state_dict(self) -> dict[str, np.ndarray]:
        """Pointers and the filled part of the storage (up to the fullest row), as numpy arrays."""
        filled = int(self.size.max(initial=0))
        # Contiguous copies: safetensors writes an array's raw buffer, and a slice is only a view.
        arrays = {name: np.ascontiguousarray(t[:, :filled].cpu().numpy()) for name, t in self.storage.items()}
        arrays["ptr"] = self.ptr.copy()
        arrays["size"] = self.size.copy()
        return arrays

    def load_state_dict(self, arrays: dict[str, np.ndarray]) -> None:
        size = np.asarray(arrays["size"], dtype=np.int64)
        if size.shape != (self.num_agents,) or (size > self.capacity).any():
            raise ValueError(
                f"replay state holds sizes {size.tolist()}, not valid for {self.num_agents} agents "
                f"with capacity {self.capacity}"
            )
        filled = int(size.max(initial=0))
        for name, dtype in _FIELDS.items():
            value = torch.as_tensor(np.asarray(arrays[name]), dtype=dtype)
            if tuple(value.shape) != self._shape(name, filled):
                expected = list(self._shape(name, filled))
                raise ValueError(f"replay array '{name}' has shape {list(value.shape)}, expected {expected}")
            self.storage[name].zero_()
            self.storage[name][:, :filled] = value.to(self.device)
        self.ptr = np.asarray(arrays["ptr"], dtype=np.int64).copy()
        self.size = size.copy()
