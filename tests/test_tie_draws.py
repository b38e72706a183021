"""The compiled tie draws are numpy's own: the same numbers and the same generator state afterwards."""

from __future__ import annotations

import numpy as np
import pytest

from dqn_transfer.compiled import kernel
from dqn_transfer.envs import tie_draws


@kernel
def _draw_all(words, bounds, out):
    for i in range(len(bounds)):
        out[i] = tie_draws.integers(words, bounds[i])


@pytest.mark.parametrize("seed", [0, 12345, [4, 1_000_003, 500, 2]])
@pytest.mark.parametrize("odd_start", [False, True])  # numpy holds half of a 64-bit output, or none
def test_compiled_draws_are_numpys_draws_and_leave_the_same_state(seed, odd_start):
    numpy_rng, compiled_rng = np.random.default_rng(seed), np.random.default_rng(seed)
    if odd_start:
        numpy_rng.integers(3), compiled_rng.integers(3)
    bounds = np.random.default_rng(7).integers(2, 9, size=20_000)
    bounds[::97] = 2**31 + 11  # wide ranges: Lemire's rejection loop runs (about half the time)
    expected = np.array([numpy_rng.integers(int(n)) for n in bounds])
    words = np.zeros(tie_draws.WORDS, dtype=np.uint64)
    tie_draws.pack(compiled_rng, words)
    drawn = np.zeros(len(bounds), dtype=np.int64)
    _draw_all(words, bounds, drawn)
    tie_draws.unpack(words, compiled_rng)
    np.testing.assert_array_equal(drawn, expected)
    assert compiled_rng.bit_generator.state == numpy_rng.bit_generator.state
    assert compiled_rng.random() == numpy_rng.random()


def test_a_generator_other_than_pcg64_is_refused():
    with pytest.raises(ValueError, match="PCG64"):
        tie_draws.pack(np.random.Generator(np.random.Philox(0)), np.zeros(tie_draws.WORDS, dtype=np.uint64))


@pytest.mark.parametrize(
    "key",
    [[0], [1, 2], [4, 1_000_003, 500, 2], [2**32, 7], [2**70 + 3, 1, 2, 3, 4, 5, 6], [123456789, 1_000_003, 0, 9]],
)
def test_compiled_seeding_makes_numpys_generator_and_its_first_child(key):
    """A generator made from its entropy in the kernels is ``default_rng(key)`` and ``spawn(1)[0]`` of it
    (short keys, keys longer than the pool of 4 words, ints wider than 32 bits)."""
    words = tie_draws.entropy_words(key)
    entropy = np.zeros((2, len(words) + 3), dtype=np.uint64)  # row 1: the same key in a wider row
    entropy[:, : len(words)] = words
    parents, children = (np.zeros((2, tie_draws.WORDS), dtype=np.uint64) for _ in range(2))
    tie_draws.seed_with_children(entropy, np.array([len(words)] * 2), parents, children)
    expected_parent, expected_child = (np.zeros(tie_draws.WORDS, dtype=np.uint64) for _ in range(2))
    tie_draws.pack(np.random.default_rng(key), expected_parent)
    tie_draws.pack(np.random.default_rng(key).spawn(1)[0], expected_child)
    for row in range(2):
        np.testing.assert_array_equal(parents[row], expected_parent)
        np.testing.assert_array_equal(children[row], expected_child)


def test_a_negative_seed_is_refused():
    with pytest.raises(ValueError, match="non-negative"):
        tie_draws.entropy_words([3, -1])


@kernel
def _explore(words, rows, agents, num_actions, uniforms, actions):
    for r in range(rows):
        for a in range(agents):
            uniforms[r, a] = tie_draws.uniform(words)
        for a in range(agents):
            actions[r, a] = tie_draws.integers(words, num_actions)


@pytest.mark.parametrize("seed", [0, 99])
def test_compiled_exploration_draws_are_epsilon_greedys(seed):
    """The DQN steps' draws: per step ``rng.random(K)`` then ``rng.integers(0, A, size=K)``, as
    ``epsilon_greedy`` takes them, with the 32-bit half numpy keeps between calls."""
    numpy_rng, compiled_rng = np.random.default_rng(seed), np.random.default_rng(seed)
    steps, agents, num_actions = 500, 3, 5
    expected_u = np.zeros((steps, agents))
    expected_a = np.zeros((steps, agents), dtype=np.int64)
    for t in range(steps):
        expected_u[t] = numpy_rng.random(agents)
        expected_a[t] = numpy_rng.integers(0, num_actions, size=agents)
    words = np.zeros(tie_draws.WORDS, dtype=np.uint64)
    tie_draws.pack(compiled_rng, words)
    uniforms, actions = np.zeros((steps, agents)), np.zeros((steps, agents), dtype=np.int64)
    _explore(words, steps, agents, num_actions, uniforms, actions)
    tie_draws.unpack(words, compiled_rng)
    assert uniforms.tobytes() == expected_u.tobytes()
    np.testing.assert_array_equal(actions, expected_a)
    assert compiled_rng.bit_generator.state == numpy_rng.bit_generator.state
