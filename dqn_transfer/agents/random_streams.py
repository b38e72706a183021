"""Counter-based random numbers: a uniform draw is a pure function of its key, computed for whole arrays.

A generator object has a position in its stream, so the draws of R replicas x K agents must be taken
one after another, and how many a step takes depends on the data (ties, live agents). Here a draw is
``uniform(seed, stream, agent, counter, slot)``, built from SplitMix64 (Steele, Lea & Flood 2014: the
generator behind ``java.util.SplittableRandom``, which Vigna recommends for seeding xoshiro): a row's
key is SplitMix64's output for (seed, purpose, agent); the draws at ``counter`` are the first outputs
of the SplitMix64 sequence seeded with that key's output at position ``counter``; the top 53 bits of
each are the uniform float in ``[0, 1)``. So:

* every agent of every replica draws in one array operation, and a fixed number of draws per
  agent-step (``slot``) makes the numbers independent of what other agents did;
* replica ``(seed s)`` of a batch draws exactly what a lone run of seed ``s`` draws (the replica's
  position in the batch is not in the key);
* a run resumes with its counters alone (no generator state to save).
"""

from __future__ import annotations

import numpy as np

from dqn_transfer.compiled import kernel

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # 2^64 / golden ratio, SplitMix64's increment
_MIX1, _MIX2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TO_UNIT = 2.0**-53


def mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finalizer of ``uint64`` values (a bijection that scatters every input bit)."""
    x = (x ^ (x >> _S30)) * _MIX1
    x = (x ^ (x >> _S27)) * _MIX2
    return x ^ (x >> _S31)


def _absorb(key: np.ndarray, value: np.ndarray | int) -> np.ndarray:
    """SplitMix64's output at position ``value`` of the sequence seeded with ``key``."""
    return mix64(key + np.asarray(value).astype(np.uint64) * _GOLDEN + _GOLDEN)


def stream_keys(seeds: np.ndarray, stream: int, agents: np.ndarray) -> np.ndarray:
    """``uint64 [N]``: the key of each row's stream, from its run's seed, the stream's purpose (a constant
    per purpose, so two purposes never share draws) and its agent within the team (computed once)."""
    with np.errstate(over="ignore"):  # uint64 arithmetic wraps by design
        key = _absorb(np.asarray(seeds).astype(np.uint64), stream)
        return _absorb(key, agents)


def uniforms(keys: np.ndarray, counters: np.ndarray | int, slots: int) -> np.ndarray:
    """``float64 [N, slots]`` uniform in ``[0, 1)``: draw ``j`` of row ``n`` at position ``counters[n]``
    of the stream ``keys[n]`` (:func:`stream_keys`).

    :param keys: ``[N]`` each row's stream key
    :param counters: ``[N]`` (or one for all rows) the position in the stream, e.g. the step
    :param slots: how many draws each row takes there
    """
    with np.errstate(over="ignore"):
        position = _absorb(np.asarray(keys), np.broadcast_to(np.asarray(counters), np.shape(keys)))
        bits = _absorb(position[:, None], np.arange(slots, dtype=np.uint64)[None, :])
    return (bits >> _S11).astype(np.float64) * _TO_UNIT


@kernel
def _mix64_one(x: np.uint64) -> np.uint64:
    x = (x ^ (x >> _S30)) * _MIX1
    x = (x ^ (x >> _S27)) * _MIX2
    return x ^ (x >> _S31)


@kernel
def draw_uniforms(key: np.uint64, counter: np.int64, out: np.ndarray) -> None:
    """:func:`uniforms` of one row, compiled: ``out [slots]`` float64, the draws at ``counter`` of the
    stream ``key`` (the same numbers, bit for bit)."""
    position = _mix64_one(key + np.uint64(counter) * _GOLDEN + _GOLDEN)
    for slot in range(out.shape[0]):
        bits = _mix64_one(position + np.uint64(slot) * _GOLDEN + _GOLDEN)
        out[slot] = np.float64(bits >> _S11) * _TO_UNIT
