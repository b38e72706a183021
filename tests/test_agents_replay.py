"""Per-agent replay rows: own pointers, wraparound, nothing from dead agents, own-range sampling."""

import numpy as np

from dqn_transfer.agents import ReplayBuffer, Transition

K, CAPACITY, OBS_DIM = 3, 4, 2


def transition(step: int, live: np.ndarray) -> Transition:
    """Every agent's transition of env step ``step``: obs = step, next_obs = step + 0.5, action = step."""
    return Transition(
        obs=np.full((K, OBS_DIM), step, dtype=np.float32),
        actions=np.full(K, step, dtype=np.int64),
        rewards=np.full(K, -step, dtype=np.float32),
        next_obs=np.full((K, OBS_DIM), step + 0.5, dtype=np.float32),
        terminated=np.full(K, step % 2 == 0),
        truncated=np.full(K, step % 3 == 0),
        live=live,
    )


def filled_buffer(seed: int = 0) -> ReplayBuffer:
    """Steps 0..5: agent 0 lives throughout, agent 1 only in steps 0 and 1, agent 2 never."""
    buffer = ReplayBuffer(K, CAPACITY, OBS_DIM, [np.random.default_rng(seed)])
    for step in range(6):
        buffer.add(transition(step, live=np.array([True, step < 2, False])))
    return buffer


def test_pointers_sizes_and_wraparound():
    buffer = filled_buffer()
    np.testing.assert_array_equal(buffer.ptr, [2, 2, 0])  # agent 0: 6 writes % 4 ; agent 1: 2 ; agent 2: 0
    np.testing.assert_array_equal(buffer.size, [4, 2, 0])
    # Agent 0's ring: slots 0, 1 were overwritten by steps 4, 5; slots 2, 3 still hold steps 2, 3.
    stored = buffer.state_dict()
    np.testing.assert_array_equal(stored["actions"][0], [4, 5, 2, 3])
    np.testing.assert_array_equal(stored["actions"][1, :2], [0, 1])
    # The dead agent added nothing: its row is untouched zeros.
    assert not stored["obs"][2].any() and not stored["terminated"][2].any()


def test_sampling_stays_in_each_agents_filled_range_and_keeps_transitions_whole():
    batch = filled_buffer().sample(200)
    assert batch.obs.shape == (K, 200, OBS_DIM) and batch.actions.shape == (K, 200)
    assert set(batch.actions[0].tolist()) == {2, 3, 4, 5}
    assert set(batch.actions[1].tolist()) == {0, 1}
    # Fields of one sample come from the same transition.
    assert batch.actions.dtype == np.int64
    actions = batch.actions.astype(np.float32)
    np.testing.assert_array_equal(batch.obs[:2, :, 0], actions[:2])
    np.testing.assert_array_equal(batch.next_obs[:2, :, 0], actions[:2] + 0.5)
    np.testing.assert_array_equal(batch.rewards[:2], -actions[:2])
    np.testing.assert_array_equal(batch.terminated[:2], (batch.actions[:2] % 2 == 0).astype(np.float32))
    # Only what the TD target reads is stored: truncation is an ordinary step for it.
    assert set(filled_buffer().state_dict()) == {"obs", "actions", "rewards", "next_obs", "terminated", "ptr", "size"}


def test_extend_appends_a_teammates_transitions_to_one_row():
    buffer = filled_buffer()
    steps = np.arange(10, 15)  # five transitions into a capacity-4 row: the oldest (10) is dropped
    buffer.extend(
        2,
        obs=np.repeat(steps[:, None], OBS_DIM, axis=1).astype(np.float32),
        actions=steps,
        rewards=np.zeros(5, dtype=np.float32),
        next_obs=np.zeros((5, OBS_DIM), dtype=np.float32),
        terminated=np.zeros(5, dtype=bool),
    )
    np.testing.assert_array_equal(buffer.state_dict()["actions"][2], [11, 12, 13, 14])
    assert buffer.ptr[2] == 0 and buffer.size[2] == 4  # (0 + 4) % 4
    np.testing.assert_array_equal(buffer.size[:2], [4, 2])  # other rows untouched


def test_state_dict_round_trip_continues_identically():
    a = filled_buffer(seed=7)
    a.sample(3)  # advance the rng
    b = ReplayBuffer(K, CAPACITY, OBS_DIM, [np.random.default_rng(99)])
    b.load_state_dict(a.state_dict())
    b.rngs[0].bit_generator.state = a.rngs[0].bit_generator.state
    assert a.state_dict()["obs"].shape == (K, 4, OBS_DIM)  # only up to the fullest row is saved
    assert np.array_equal(a.storage, b.storage)
    batch_a, batch_b = a.sample(16), b.sample(16)
    for field_a, field_b in zip(batch_a, batch_b):
        assert np.array_equal(field_a, field_b)


def test_replica_rows_sample_exactly_as_their_own_buffer_would():
    """Two replicas of K rows in one buffer: replica 1's rows, its generator and its samples are those of
    a lone buffer given the same data and seed, whatever replica 0 holds."""
    joint = ReplayBuffer(2 * K, CAPACITY, OBS_DIM, [np.random.default_rng(5), np.random.default_rng(6)])
    lone = ReplayBuffer(K, CAPACITY, OBS_DIM, [np.random.default_rng(6)])
    for step in range(6):
        mine, other = transition(step, np.array([True, step < 3, True])), transition(100 + step, np.ones(K, bool))
        joint.add(Transition(*(np.concatenate([a, b]) for a, b in zip(other, mine))))
        lone.add(mine)
    for _ in range(3):
        batch, expected = joint.sample(8), lone.sample(8)
        for field, want in zip(batch, expected):
            assert np.array_equal(field[K:], want)
    halves = joint.state_dict(slice(K, 2 * K)), lone.state_dict()
    assert all(np.array_equal(halves[0][name], halves[1][name]) for name in halves[1])
