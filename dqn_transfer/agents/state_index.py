"""How a tabular learner numbers the observations its tables hold: one interface, two indexes.

* :class:`DenseIndex`: the game numbers its observations itself (a :class:`StateCode`: a bijection onto
  ``0..num_ids-1``, e.g. the treasure hunt's, :mod:`dqn_transfer.envs.observation_code`), so a table is
  an array over every id, allocated once; a lookup is arithmetic on the observation's segments.
* :class:`MetOrderIndex`: any game (one with no code, or a code whose tables would not fit): each
  replica's observations get ids in the order they are first met, found through a hash index; its
  arrays grow (doubling) as new observations come.

A replica's agents share its index (they play one game). An id is a row of the learner's arrays
``[rows, capacity, ...]``; the observation of an id is what checkpoints store, so both indexes write
the same checkpoints.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple, Protocol

import numpy as np

from dqn_transfer.agents.random_streams import mix64

_INITIAL_STATES = 64  # ids a met-order index holds before it first grows (doubling)


class StateCode(Protocol):
    """A game's numbering of its observations: ``num_ids`` ids, a bijection on what the game produces."""

    num_ids: int

    def encode(self, obs: np.ndarray, replicas: np.ndarray) -> np.ndarray:
        """``int64 [N]``: each observation's id (``obs [N, D]`` of replica ``replicas[n]``), -1 for a
        vector that is no observation of that replica's game."""
        ...

    def decode(self, replica: int, ids: np.ndarray) -> np.ndarray:
        """``float32 [N, D]``: the observations of replica ``replica`` with ids ``ids [N]``."""
        ...


class Lookup(NamedTuple):
    """The ids of a lookup, and the states it met for the first time (their entries need start values)."""

    ids: np.ndarray  # int64 [N]
    new_replicas: np.ndarray  # int64 [M]: the replica of each new state
    new_states: np.ndarray  # int64 [M]


_NOTHING_NEW = np.zeros(0, dtype=np.int64)


class StateIndex(ABC):
    """Ids of each replica's observations; the learner's arrays hold ``capacity`` ids per row."""

    capacity: int

    @abstractmethod
    def lookup(self, obs: np.ndarray, rows: np.ndarray) -> Lookup:
        """The id of each row's observation ``obs [N, D]`` in its replica's index (``rows [N]``, may
        repeat); raises ``ValueError`` for an observation the index cannot number."""

    @abstractmethod
    def count(self, replica: int) -> int:
        """The ids in use in ``replica``: ``0..count-1``."""

    @abstractmethod
    def observations(self, replica: int, states: np.ndarray) -> np.ndarray:
        """``float32 [N, D]``: the observations of ``replica`` with ids ``states``."""


class DenseIndex(StateIndex):
    """Every id of a :class:`StateCode`, always there: nothing is ever new, nothing grows."""

    def __init__(self, code: StateCode, row_replica: np.ndarray) -> None:
        """
        :param code: the game's numbering of its observations
        :param row_replica: ``[rows]`` each learner row's replica
        """
        self.code = code
        self.row_replica = row_replica
        self.capacity = int(code.num_ids)

    def lookup(self, obs: np.ndarray, rows: np.ndarray) -> Lookup:
        ids = self.code.encode(obs, self.row_replica[rows])
        unknown = np.flatnonzero(ids < 0)
        if unknown.size:
            raise ValueError(
                f"{np.asarray(obs)[unknown[0]].tolist()} is no observation of this game (not a state of its table)"
            )
        return Lookup(ids, _NOTHING_NEW, _NOTHING_NEW)

    def count(self, replica: int) -> int:
        return self.capacity

    def observations(self, replica: int, states: np.ndarray) -> np.ndarray:
        return self.code.decode(replica, states)


def observation_hashes(bits: np.ndarray, replicas: np.ndarray) -> np.ndarray:
    """``uint64 [N]``: a hash of each row's (replica, observation bits ``[N, D]`` uint32) pair. Each
    value is mixed with its column first, so the sum over columns tells reordered values apart."""
    columns = np.arange(bits.shape[1], dtype=np.uint64) << np.uint64(32)
    with np.errstate(over="ignore"):  # uint64 arithmetic wraps by design
        values = mix64(bits.astype(np.uint64) | columns).sum(axis=1, dtype=np.uint64)
        return mix64(values + mix64(np.asarray(replicas).astype(np.uint64)))


class MetOrderIndex(StateIndex):
    """Each replica's observations (compared bit for bit), numbered in the order they are first met."""

    def __init__(self, num_replicas: int, obs_dim: int, row_replica: np.ndarray) -> None:
        """
        :param num_replicas: R, one index each
        :param obs_dim: D, the observation's width
        :param row_replica: ``[rows]`` each learner row's replica
        """
        self.row_replica = row_replica
        self.capacity = _INITIAL_STATES
        # Each replica's observations by id (its agents share the index), and how many it has.
        self._ids: list[dict[bytes, int]] = [{} for _ in range(num_replicas)]
        # In front of the dicts, for lookups of all rows at once: the known (replica, observation) pairs'
        # hashes, sorted, and their ids. A hit is checked against the stored observation, so a hash
        # collision only sends that observation to its dict.
        self._hashes = np.zeros(0, dtype=np.uint64)
        self._hashed_ids = np.zeros(0, dtype=np.int64)
        self._new_hashes: list[tuple[int, int]] = []  # (hash, id) of the states added in this lookup
        self.state_keys = np.zeros((num_replicas, _INITIAL_STATES, obs_dim), dtype=np.float32)
        self.num_states = np.zeros(num_replicas, dtype=np.int64)
        rows = len(row_replica)
        self._last_obs = np.zeros((rows, obs_dim), dtype=np.uint32)  # each row's last observation's bits
        self._last_ids = np.full(rows, -1, dtype=np.int64)  # ... and its id (-1: none yet)

    def count(self, replica: int) -> int:
        return int(self.num_states[replica])

    def observations(self, replica: int, states: np.ndarray) -> np.ndarray:
        return self.state_keys[replica, states]

    def lookup(self, obs: np.ndarray, rows: np.ndarray) -> Lookup:
        """New observations get the next ids. A row's last observation and id are remembered: the loop
        asks for the same observation again (act on s', then update on it), so only the rows whose
        observation changed are looked up."""
        obs = np.ascontiguousarray(obs, dtype=np.float32)
        rows = np.asarray(rows, dtype=np.int64)
        bits = obs.view(np.uint32)  # compared bit for bit, as the index's keys are
        same = (self._last_ids[rows] >= 0) & (bits == self._last_obs[rows]).all(axis=1)
        ids = self._last_ids[rows]
        changed = np.flatnonzero(~same)
        new: list[tuple[int, int]] = []
        if changed.size:
            replicas = self.row_replica[rows[changed]]
            hashes = observation_hashes(bits[changed], replicas)
            found = self._known_ids(hashes, replicas, bits[changed])
            for n in np.flatnonzero(found < 0).tolist():  # unseen, or a hash collision: the dict decides
                r, key = int(replicas[n]), obs[changed[n]].tobytes()
                known = self._ids[r].get(key)
                if known is None:
                    known = self._new_state(r, key, obs[changed[n]], int(hashes[n]))
                    new.append((r, known))
                found[n] = known
            self._index_new_hashes()
            ids[changed] = found
            # Remember each row's last looked-up observation (a row may come more than once).
            last = len(changed) - 1 - np.unique(rows[changed][::-1], return_index=True)[1]
            self._last_obs[rows[changed[last]]] = bits[changed[last]]
            self._last_ids[rows[changed[last]]] = found[last]
        if not new:
            return Lookup(ids, _NOTHING_NEW, _NOTHING_NEW)
        new_replicas, new_states = np.array(new, dtype=np.int64).T
        return Lookup(ids, new_replicas, new_states)

    def _known_ids(self, hashes: np.ndarray, replicas: np.ndarray, bits: np.ndarray) -> np.ndarray:
        """The ids the hash index gives (``-1``: no hit, or a hit on another observation)."""
        at = np.minimum(np.searchsorted(self._hashes, hashes), max(len(self._hashes) - 1, 0))
        hit = np.flatnonzero(self._hashes[at] == hashes) if len(self._hashes) else np.zeros(0, dtype=np.int64)
        found = np.full(len(hashes), -1, dtype=np.int64)
        candidates = self._hashed_ids[at[hit]]
        stored = self.state_keys[replicas[hit], candidates].view(np.uint32)
        found[hit] = np.where((stored == bits[hit]).all(axis=1), candidates, -1)
        return found

    def _new_state(self, r: int, key: bytes, obs: np.ndarray, hashed: int) -> int:
        state = int(self.num_states[r])
        if state == self.capacity:
            self.capacity *= 2
            self.state_keys = np.concatenate([self.state_keys, np.zeros_like(self.state_keys)], axis=1)
        self._ids[r][key] = state
        self._new_hashes.append((hashed, state))
        self.state_keys[r, state] = obs
        self.num_states[r] += 1
        return state

    def _index_new_hashes(self) -> None:
        """Add the states of this lookup to the hash index, one insertion for all. A hash already
        there (a collision) keeps its first state; the other observation is found in its dict."""
        if not self._new_hashes:
            return
        hashes = np.array([hashed for hashed, _ in self._new_hashes], dtype=np.uint64)
        states = np.array([state for _, state in self._new_hashes], dtype=np.int64)
        self._new_hashes.clear()
        hashes, first = np.unique(hashes, return_index=True)
        at = np.searchsorted(self._hashes, hashes)
        fresh = self._hashes[np.minimum(at, len(self._hashes) - 1)] != hashes if len(self._hashes) else at >= 0
        self._hashes = np.insert(self._hashes, at[fresh], hashes[fresh])
        self._hashed_ids = np.insert(self._hashed_ids, at[fresh], states[first][fresh])
