"""numpy's default generator inside the compiled kernels: ``integers(n)`` and ``random()``.

A replica's chest ties are drawn from its ``numpy.random.Generator`` (``default_rng``: the PCG64 bit
generator), ``rng.integers(contenders)``. The rules' kernels draw them themselves, so a step never
returns to Python for a tie: the generator's state is copied into six words (:func:`pack`), the
kernels advance them exactly as numpy advances its own state (:func:`integers`: PCG64's 128-bit
step and XSL-RR output, halves of it as 32-bit draws, Lemire's bounded draw as numpy's
``random_bounded_uint64`` makes it for a range below 2**32), and the words go back into the generator
(:func:`unpack`). The same numbers and the same generator state as numpy's, bit for bit
(``tests/test_tie_draws.py``). The compiled DQN steps draw their exploration the same way
(:func:`uniform`, :func:`integers`).

A batch of evaluation episodes needs a new generator per episode (and a child of it): :func:`seed`
makes its packed state from its entropy as ``default_rng`` does (numpy's ``SeedSequence``, then
PCG64's seeding), in a fraction of a microsecond where numpy takes about 30 µs per pair.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dqn_transfer.compiled import kernel

# The words of a packed state: the 128-bit LCG state and increment as (high, low) 64-bit halves, then
# numpy's buffered half of the last 64-bit output (whether there is one, and its value).
STATE_HIGH, STATE_LOW, INC_HIGH, INC_LOW, HAS_UINT32, UINTEGER = range(6)
WORDS = 6
_MULTIPLIER_HIGH = np.uint64(0x2360ED051FC65DA4)  # PCG's default 128-bit multiplier
_MULTIPLIER_LOW = np.uint64(0x4385DF649FCCF645)
_LOW32 = np.uint64(0xFFFFFFFF)
_LOW64 = (1 << 64) - 1
_TO_UNIT = 2.0**-53


def pack(generator: np.random.Generator, words: np.ndarray) -> None:
    """Copy ``generator``'s state into ``words [WORDS] uint64``."""
    state = generator.bit_generator.state
    if state["bit_generator"] != "PCG64":
        raise ValueError(
            f"chest ties are drawn from a PCG64 generator (numpy.random.default_rng), got {state['bit_generator']}"
        )
    lcg, increment = state["state"]["state"], state["state"]["inc"]
    words[:] = (lcg >> 64, lcg & _LOW64, increment >> 64, increment & _LOW64, state["has_uint32"], state["uinteger"])


def unpack(words: np.ndarray, generator: np.random.Generator) -> None:
    """Set ``generator``'s state to the packed ``words`` (a :func:`pack` ed state, advanced)."""
    high, low, inc_high, inc_low, has_uint32, uinteger = (int(word) for word in words)
    generator.bit_generator.state = {
        "bit_generator": "PCG64",
        "state": {"state": (high << 64) | low, "inc": (inc_high << 64) | inc_low},
        "has_uint32": has_uint32,
        "uinteger": uinteger,
    }


@kernel
def _multiply_high(a, b):
    """The high 64 bits of the 128-bit product of two uint64 values (from 32-bit halves)."""
    a_low, a_high = a & _LOW32, a >> np.uint64(32)
    b_low, b_high = b & _LOW32, b >> np.uint64(32)
    low_high = a_low * b_high
    high_low = a_high * b_low
    middle = ((a_low * b_low) >> np.uint64(32)) + (high_low & _LOW32) + low_high
    return a_high * b_high + (high_low >> np.uint64(32)) + (middle >> np.uint64(32))


@kernel
def _add_128(words, high, low):
    """The state plus ``(high, low)``, mod 2**128."""
    new_low = words[STATE_LOW] + low
    carry = np.uint64(1) if new_low < low else np.uint64(0)
    words[STATE_HIGH], words[STATE_LOW] = words[STATE_HIGH] + high + carry, new_low


@kernel
def _lcg_step(words):
    """PCG64's LCG step: ``state * multiplier + inc`` (mod 2**128)."""
    high, low = words[STATE_HIGH], words[STATE_LOW]
    product_low = low * _MULTIPLIER_LOW
    words[STATE_HIGH] = _multiply_high(low, _MULTIPLIER_LOW) + high * _MULTIPLIER_LOW + low * _MULTIPLIER_HIGH
    words[STATE_LOW] = product_low
    _add_128(words, words[INC_HIGH], words[INC_LOW])


@kernel
def next_uint64(words):
    """PCG64's next output: the LCG step, then XSL-RR."""
    _lcg_step(words)
    new_high, new_low = words[STATE_HIGH], words[STATE_LOW]
    mixed = new_high ^ new_low
    rotation = new_high >> np.uint64(58)
    return (mixed >> rotation) | (mixed << ((np.uint64(64) - rotation) & np.uint64(63)))


@kernel
def next_uint32(words):
    """numpy's 32-bit draw: the low half of a new 64-bit output, its high half kept for the next."""
    if words[HAS_UINT32]:
        words[HAS_UINT32] = np.uint64(0)
        return words[UINTEGER]
    drawn = next_uint64(words)
    words[HAS_UINT32] = np.uint64(1)
    words[UINTEGER] = drawn >> np.uint64(32)
    return drawn & _LOW32


@kernel
def uniform(words):
    """``Generator.random()``: a float64 in ``[0, 1)`` from the top 53 bits of a 64-bit output (numpy's
    ``next_double``; the buffered 32-bit half is left as it is)."""
    return np.float64(next_uint64(words) >> np.uint64(11)) * _TO_UNIT


@kernel
def integers(words, n):
    """``Generator.integers(n)`` for ``2 <= n < 2**32``: Lemire's multiply-and-reject on 32-bit draws."""
    bound = np.uint64(n)
    scaled = next_uint32(words) * bound
    leftover = scaled & _LOW32
    if leftover < bound:
        threshold = (_LOW32 - (bound - np.uint64(1))) % bound
        while leftover < threshold:
            scaled = next_uint32(words) * bound
            leftover = scaled & _LOW32
    return np.int64(scaled >> np.uint64(32))


# ------------------------------------------------------------------------------------ seeding
# numpy's SeedSequence: a pool of 4 32-bit words, hashed and mixed with these constants (numpy's
# bit_generator.pyx), then 64-bit words drawn from the pool to seed PCG64.
POOL_SIZE = 4
_INIT_A, _MULT_A = np.uint64(0x43B0D7E5), np.uint64(0x931E8875)
_INIT_B, _MULT_B = np.uint64(0x8B51F9DD), np.uint64(0x58F38DED)
_MIX_MULT_L, _MIX_MULT_R = np.uint64(0xCA01F9DD), np.uint64(0x4973F715)
_XSHIFT = np.uint64(16)


def entropy_words(values: Sequence[int]) -> list[int]:
    """``SeedSequence(values)``'s entropy as numpy assembles it: each non-negative int as its 32-bit
    words, lowest first (0 as one word)."""
    words = []
    for value in values:
        value = int(value)
        if value < 0:
            raise ValueError(f"a seed's entropy must be non-negative, got {value}")
        words.append(value & 0xFFFFFFFF)
        value >>= 32
        while value:
            words.append(value & 0xFFFFFFFF)
            value >>= 32
    return words


@kernel
def _hashmix(value, hash_const):
    """SeedSequence's hash of one word; ``hash_const [1]`` moves on."""
    value = (value ^ hash_const[0]) & _LOW32
    hash_const[0] = (hash_const[0] * _MULT_A) & _LOW32
    value = (value * hash_const[0]) & _LOW32
    return value ^ (value >> _XSHIFT)


@kernel
def _mix(x, y):
    result = (_MIX_MULT_L * x - _MIX_MULT_R * y) & _LOW32
    return result ^ (result >> _XSHIFT)


@kernel
def seed(entropy, words):
    """``words``: the packed state of ``default_rng(SeedSequence(entropy))``, ``entropy`` the assembled
    32-bit words (:func:`entropy_words`)."""
    pool = np.zeros(POOL_SIZE, dtype=np.uint64)
    hash_const = np.full(1, _INIT_A)
    for i in range(POOL_SIZE):
        pool[i] = _hashmix(entropy[i] if i < len(entropy) else np.uint64(0), hash_const)
    for source in range(POOL_SIZE):
        for target in range(POOL_SIZE):
            if source != target:
                pool[target] = _mix(pool[target], _hashmix(pool[source], hash_const))
    for source in range(POOL_SIZE, len(entropy)):
        for target in range(POOL_SIZE):
            pool[target] = _mix(pool[target], _hashmix(entropy[source], hash_const))
    # generate_state(4, uint64): 8 words from the pool in turn, paired little-endian
    seeded = np.zeros(4, dtype=np.uint64)
    hash_b = _INIT_B
    for i in range(8):
        value = pool[i % POOL_SIZE] ^ hash_b
        hash_b = (hash_b * _MULT_B) & _LOW32
        value = (value * hash_b) & _LOW32
        seeded[i // 2] |= (value ^ (value >> _XSHIFT)) << np.uint64(32 * (i % 2))
    # PCG64's srandom: inc = sequence * 2 + 1; state 0, a step, plus the initial state, a step
    words[INC_HIGH] = (seeded[2] << np.uint64(1)) | (seeded[3] >> np.uint64(63))
    words[INC_LOW] = (seeded[3] << np.uint64(1)) | np.uint64(1)
    words[STATE_HIGH], words[STATE_LOW] = np.uint64(0), np.uint64(0)
    _lcg_step(words)
    _add_128(words, seeded[0], seeded[1])
    _lcg_step(words)
    words[HAS_UINT32], words[UINTEGER] = np.uint64(0), np.uint64(0)


@kernel
def seed_with_children(entropy, lengths, parents, children):
    """Row g: ``parents[g]`` the packed ``default_rng`` of the entropy ``entropy[g, :lengths[g]]`` and
    ``children[g]`` its ``spawn(1)[0]`` (whose entropy is the parent's, padded with zeros to the pool's
    4 words, then its spawn key 0)."""
    for g in range(len(lengths)):
        own = entropy[g, : lengths[g]]
        seed(own, parents[g])
        child = np.zeros(max(len(own), POOL_SIZE) + 1, dtype=np.uint64)
        child[: len(own)] = own
        seed(child, children[g])
