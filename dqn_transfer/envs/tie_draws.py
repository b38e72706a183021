"""The chest ties' draws inside the compiled rules: numpy's default generator and its ``integers(n)``.

A replica's chest ties are drawn from its ``numpy.random.Generator`` (``default_rng``: the PCG64 bit
generator), ``rng.integers(contenders)``. The rules' kernels draw them themselves, so a step never
returns to Python for a tie: the generator's state is copied into six words (:func:`pack`), the
kernels advance them exactly as numpy advances its own state (:func:`integers`: PCG64's 128-bit
step and XSL-RR output, halves of it as 32-bit draws, Lemire's bounded draw as numpy's
``random_bounded_uint64`` makes it for a range below 2**32), and the words go back into the generator
(:func:`unpack`). The same numbers and the same generator state as numpy's, bit for bit
(``tests/test_tie_draws.py``).
"""

from __future__ import annotations

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
def next_uint64(words):
    """PCG64's next output: the LCG steps ``state * multiplier + inc`` (mod 2**128), then XSL-RR."""
    high, low = words[STATE_HIGH], words[STATE_LOW]
    product_low = low * _MULTIPLIER_LOW
    product_high = _multiply_high(low, _MULTIPLIER_LOW) + high * _MULTIPLIER_LOW + low * _MULTIPLIER_HIGH
    new_low = product_low + words[INC_LOW]
    carry = np.uint64(1) if new_low < product_low else np.uint64(0)
    new_high = product_high + words[INC_HIGH] + carry
    words[STATE_HIGH], words[STATE_LOW] = new_high, new_low
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
