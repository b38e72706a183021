"""The batched DQN learner: schedules, target syncs, parameter sharing, freezing, resume, learning."""

import json

import numpy as np
import pytest
import torch
from safetensors.numpy import load as load_numpy
from safetensors.numpy import save as save_numpy

from dqn_transfer import enums
from dqn_transfer.agents import DQNLearner, TabularLearner, Transition, linear_schedule, make_learner
from dqn_transfer.agents.numpy_dqn import NumpyDQNLearner
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm, Engine, Mixer, resolve_engine

LAYOUT = [("position", 3), ("treasures", 1)]
D, A = 4, 2


def dqn(num_agents: int = 2, seed: int = 0, double: bool = False, **kwargs) -> DQNLearner:
    hp = {**dict(batch_size=4, buffer_size=32, learning_starts=0, train_freq=1, hidden=[8]), **kwargs}
    algorithm = Algorithm.double_dqn if double else Algorithm.dqn
    return DQNLearner(num_agents, LAYOUT, A, AgentConfig(algorithm=algorithm, **hp), seed=seed)


def step_of(t: dict, actions: np.ndarray, live: np.ndarray | None = None) -> Transition:
    """The joint transition of one ``random_steps`` entry with the actions taken."""
    return Transition(
        t["obs"],
        actions,
        t["rewards"],
        t["next_obs"],
        t["terminated"],
        t["truncated"],
        t["live"] if live is None else live,
    )


def random_steps(num_agents: int, n: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [
        dict(
            obs=rng.random((num_agents, D), dtype=np.float32),
            rewards=rng.normal(size=num_agents).astype(np.float32),
            next_obs=rng.random((num_agents, D), dtype=np.float32),
            terminated=rng.random(num_agents) < 0.1,
            truncated=rng.random(num_agents) < 0.1,
            live=rng.random(num_agents) < 0.9,
        )
        for _ in range(n)
    ]


def run(learner: DQNLearner, steps: list[dict], first_step: int = 1, epsilon: float = 0.3) -> list:
    """Feed transitions to act/update like the trainer does; returns the actions taken."""
    taken = []
    for step, t in enumerate(steps, start=first_step):
        actions = learner.act(t["obs"], t["live"], epsilon)
        learner.update(step_of(t, actions), step)
        taken.append(actions)
    return taken


def weights(network) -> list[torch.Tensor]:
    return [t.clone() for t in network.tensors]


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b))


def test_hard_target_copy_exactly_at_multiples_of_target_update():
    learner = dqn(target_update=3, tau=1.0)
    initial_target = weights(learner.target_network)
    for step, t in enumerate(random_steps(2, 7), start=1):
        learner.update(step_of(t, np.zeros(2, np.int64), np.ones(2, bool)), step)
        synced = same(weights(learner.target_network), weights(learner.q_network))
        assert synced == (step % 3 == 0), step  # online changes every step; target catches up at 3, 6
        if step == 3:
            at_three = weights(learner.target_network)
        if step in (4, 5):
            assert same(weights(learner.target_network), at_three)
        if step < 3:
            assert same(weights(learner.target_network), initial_target)


def test_polyak_target_moves_by_tau_after_each_gradient_step():
    learner = dqn(tau=0.25, target_update=1)
    target_before = weights(learner.target_network)
    run(learner, random_steps(2, 1))
    for old, new, online in zip(target_before, weights(learner.target_network), weights(learner.q_network)):
        # target <- target + tau * (online - target)
        torch.testing.assert_close(new, old + 0.25 * (online - old))


@pytest.mark.parametrize("learner_class", [DQNLearner, NumpyDQNLearner])
def test_a_target_synced_every_step_follows_the_online_weights_of_each_step(learner_class):
    # The learner applies its syncs late, several in one pass; the target must still be what a sync at the
    # end of every step makes it, each toward that step's online weights, around gradient steps and an exchange.
    hp = dict(batch_size=4, buffer_size=32, learning_starts=2, train_freq=3, hidden=[8], tau=0.3)
    learner = learner_class(2, LAYOUT, A, AgentConfig(algorithm="dqn", **hp), seed=0)
    tau = np.float32(0.3)
    expected = [{k[7:]: v for k, v in learner.agent_tensors(i).items() if k.startswith("target.")} for i in range(2)]
    for step, t in enumerate(random_steps(2, 11), start=1):
        learner.update(step_of(t, learner.act(t["obs"], t["live"], 0.3)), step)
        for i, target in enumerate(expected):
            online = learner.get_member_weights(i)
            for name in target:
                target[name] = target[name] + tau * (online[name] - target[name])
        if step == 6:  # a best copy moves agent 0's online weights between two syncs
            learner.soft_copy_best(best=1, tau=0.5)
    for i, target in enumerate(expected):
        found = {k[7:]: v for k, v in learner.agent_tensors(i).items() if k.startswith("target.")}
        for name, value in target.items():
            if learner_class is NumpyDQNLearner:  # the same float32 operations, one by one
                assert np.array_equal(found[name], value), name
            else:  # torch's lerp may fuse its multiply-add
                np.testing.assert_allclose(found[name], value, rtol=1e-6, atol=1e-7)


def test_training_starts_after_learning_starts_every_train_freq_steps():
    learner = dqn(learning_starts=3, train_freq=2)
    trained = []
    for step, t in enumerate(random_steps(2, 8), start=1):
        out = learner.update(step_of(t, np.zeros(2, np.int64), np.ones(2, bool)), step)
        trained.append(bool(np.isfinite(out.td_loss).all()))
    # steps > 3 and even: 4, 6, 8
    assert trained == [False, False, False, True, False, True, False, True]
    assert learner.num_gradient_steps == 3


def constant_q_learner(c: float, **kwargs) -> DQNLearner:
    """Zero weights everywhere and output bias c: Q(s, a) = c for every s and a."""
    learner = dqn(hidden=[4], batch_size=1, **kwargs)
    state = {
        "layers.0.weight": np.zeros((4, D), np.float32),
        "layers.0.bias": np.zeros(4, np.float32),
        "layers.1.weight": np.zeros((A, 4), np.float32),
        "layers.1.bias": np.full(A, c, np.float32),
    }
    for i in range(learner.num_agents):
        learner.load_agent_tensors(i, {f"q.{k}": v for k, v in state.items()})
    return learner


@pytest.mark.parametrize("double", [False, True])
def test_truncated_transition_bootstraps_and_terminated_does_not(double):
    learner = constant_q_learner(1.0, double=double, gamma=0.5)
    obs = np.zeros((2, D), np.float32)
    out = learner.update(
        Transition(
            obs,
            np.array([0, 1]),
            np.zeros(2, np.float32),
            obs,
            terminated=np.array([False, True]),
            truncated=np.array([True, False]),
            live=np.ones(2, bool),
        ),
        step=1,
    )
    # agent 0, truncated:  y = 0 + 0.5 * 1 = 0.5, d = 1 - 0.5 = 0.5 -> Huber 0.5 * 0.5^2 = 0.125
    # agent 1, terminated: y = 0,                  d = 1 - 0 = 1    -> Huber 1 - 0.5     = 0.5
    np.testing.assert_allclose(out.td_loss, [0.125, 0.5])
    np.testing.assert_allclose(out.q_mean, [1.0, 1.0])


def test_dead_agent_has_no_update_until_it_has_data():
    learner = dqn()
    t = random_steps(2, 1)[0]
    out = learner.update(step_of(t, np.zeros(2, np.int64), np.array([True, False])), step=1)
    assert np.isfinite(out.td_loss[0]) and np.isnan(out.td_loss[1]) and np.isnan(out.q_mean[1])
    np.testing.assert_array_equal(learner.replay.size, [1, 0])
    # Agent 1's network did not move (zero gradient, zero Adam moments).
    fresh = dqn()
    assert same([t[1] for t in learner.q_network.tensors], [t[1] for t in fresh.q_network.tensors])


def test_share_parameters_one_network_for_all_agents():
    learner = dqn(num_agents=3, share_parameters=True)
    assert learner.q_network.num_members == 1
    run(learner, random_steps(3, 10))
    first = learner.agent_tensors(0)
    for i in (1, 2):
        assert all(np.array_equal(first[name], t) for name, t in learner.agent_tensors(i).items())
    # Same observation -> same greedy action for every agent.
    obs = np.repeat(np.random.default_rng(0).random((1, D), dtype=np.float32), 3, axis=0)
    actions = learner.greedy(obs, np.ones(3, bool))
    assert len(set(actions.tolist())) == 1
    # Setting "agent 2's" weights sets everyone's.
    new = {name: np.zeros_like(t) for name, t in learner.get_member_weights(2).items()}
    learner.set_member_weights(2, new)
    assert all(np.array_equal(t, new[name]) for name, t in learner.get_member_weights(0).items())
    assert learner.network_meta()["share_parameters"] is True


def test_member_weights_exchange_between_agents():
    learner = dqn(num_agents=2)
    learner.set_member_weights(1, learner.get_member_weights(0))
    obs = np.repeat(np.random.default_rng(0).random((1, D), dtype=np.float32), 2, axis=0)
    q = learner.q_values(obs)
    assert q.shape == (2, A) and np.array_equal(q[0], q[1])


def test_freeze_keeps_layers_fixed_for_all_agents():
    learner = dqn(hidden=[8, 8])
    learner.freeze([0, -1])  # input and output layers
    before = weights(learner.q_network)
    run(learner, random_steps(2, 10))
    after = learner.q_network.named_tensors()
    for name, old in zip(learner.q_network.tensor_names, before):
        changed = not torch.equal(after[name], old)
        assert changed == (name in ("weight_1", "bias_1")), name
    assert learner.frozen_layers == [0, 2]


def test_agent_tensor_names_and_shapes():
    tensors = dqn(hidden=[8, 6]).agent_tensors(1)
    expected = {}
    for net in ("q", "target"):
        for l, (fan_in, fan_out) in enumerate([(D, 8), (8, 6), (6, A)]):
            expected[f"{net}.layers.{l}.weight"] = (fan_out, fan_in)  # nn.Linear: [out, in]
            expected[f"{net}.layers.{l}.bias"] = (fan_out,)
    assert {name: tuple(t.shape) for name, t in tensors.items()} == expected
    assert all(isinstance(t, np.ndarray) and t.flags.c_contiguous and t.dtype == np.float32 for t in tensors.values())


def test_same_seed_same_actions_and_weights():
    steps = random_steps(2, 20)
    a, b = dqn(seed=4, double=True), dqn(seed=4, double=True)
    assert all(np.array_equal(x, y) for x, y in zip(run(a, steps, epsilon=0.5), run(b, steps, epsilon=0.5)))
    assert same(weights(a.q_network), weights(b.q_network))
    assert not same(weights(dqn(seed=5).q_network), weights(dqn(seed=4).q_network))


@pytest.mark.parametrize("share_parameters", [False, True])
def test_training_state_round_trip_continues_bit_identically(share_parameters):
    steps = random_steps(3, 50, seed=1)
    kwargs = dict(num_agents=3, share_parameters=share_parameters, double=True, tau=0.5, target_update=1)
    a = dqn(seed=0, **kwargs)
    a.freeze([0])
    run(a, steps[:30])

    arrays, meta = a.training_state()
    # What the checkpoint module does: numpy arrays through safetensors, meta through JSON.
    arrays, meta = load_numpy(save_numpy(arrays)), json.loads(json.dumps(meta))
    b = dqn(seed=123, **kwargs)  # different seed: everything must come from the saved state
    for i in range(3):
        b.load_agent_tensors(i, a.agent_tensors(i))
    b.load_training_state(arrays, meta)

    actions_a, actions_b = run(a, steps[30:], first_step=31), run(b, steps[30:], first_step=31)
    assert all(np.array_equal(x, y) for x, y in zip(actions_a, actions_b))
    for net_a, net_b in ((a.q_network, b.q_network), (a.target_network, b.target_network)):
        for (name, p), q in zip(net_a.named_tensors().items(), net_b.tensors):
            assert torch.equal(p, q), name
    assert b.frozen_layers == [0] and a.num_gradient_steps == b.num_gradient_steps


def test_engine_auto_is_numpy_on_the_cpu_and_torch_elsewhere(monkeypatch):
    dqn, none = Algorithm.dqn, Mixer.none
    assert resolve_engine("auto", "cpu", dqn, none) is Engine.numpy
    assert resolve_engine("auto", "cuda", dqn, none) is Engine.torch
    assert resolve_engine("auto", "auto", dqn, none) is Engine.torch
    assert resolve_engine("torch", "cpu", dqn, none) is Engine.torch
    assert resolve_engine("numpy", "cpu", dqn, none) is Engine.numpy
    assert AgentConfig().engine is Engine.auto
    assert isinstance(make_learner(AgentConfig(), 2, LAYOUT, A, seed=0), NumpyDQNLearner)
    # A loss the numpy engine does not implement (here: VDN, as if it were new) runs on torch.
    monkeypatch.setattr(enums, "NUMPY_MIXERS", (Mixer.none,))
    assert resolve_engine("auto", "cpu", dqn, Mixer.vdn) is Engine.torch
    assert isinstance(make_learner(AgentConfig(mixer=Mixer.vdn), 2, LAYOUT, A, seed=0), DQNLearner)


def test_make_learner_builds_each_algorithm_from_its_config():
    cfg = dict(lr=0.1, gamma=0.9, hidden=[16], batch_size=8, buffer_size=100, engine=Engine.torch)
    for algorithm, cls in [
        ("sarsa", TabularLearner),
        ("qlearning", TabularLearner),
        ("dqn", DQNLearner),
        ("double_dqn", DQNLearner),
    ]:
        learner = make_learner(AgentConfig(algorithm=Algorithm(algorithm), **cfg), 2, LAYOUT, A, seed=0)
        assert isinstance(learner, cls) and learner.algorithm == algorithm
        assert learner.lr == 0.1 and learner.gamma == 0.9
    double = make_learner(AgentConfig(algorithm=Algorithm.double_dqn, **cfg), 2, LAYOUT, A, seed=0)
    assert double.double and double.batch_size == 8 and double.replay.capacity == 100 and double.hidden == [16]
    with pytest.raises(ValueError, match="'ppo' is not a valid Algorithm"):
        make_learner(AgentConfig(algorithm="ppo"), 2, LAYOUT, A, seed=0)
    with pytest.raises(ValueError, match="trains the DQN family, not sarsa"):
        DQNLearner(2, LAYOUT, A, AgentConfig(algorithm=Algorithm.sarsa))


@pytest.mark.slow
def test_dqn_learns_a_corridor():
    """Corridor of 5 cells, start at 0, +1 for reaching cell 4 (terminal), 0 otherwise, 20-step limit.

    Q*(s, right) = 0.9^(3-s) for s = 0..3, so the greedy policy must go right everywhere.
    Four agents learn their own corridor side by side in the batched network, each from its own initial
    weights and exploration: four seeds of one learner. At least 3 of the 4 must learn Q* (one seed may
    be slow; which one depends on float rounding, so on the CPU).
    """
    k, n, gamma, total = 4, 5, 0.9, 2000
    hp = AgentConfig(
        algorithm=Algorithm.dqn,
        lr=3e-3,
        gamma=gamma,
        batch_size=32,
        buffer_size=2000,
        learning_starts=100,
        train_freq=1,
        target_update=50,
        tau=1.0,
        hidden=[32],
    )
    learner = DQNLearner(k, [("position", n)], 2, hp, seed=0)
    eye = np.eye(n, dtype=np.float32)
    pos, t_in_episode = np.zeros(k, int), np.zeros(k, int)
    for step in range(1, total + 1):
        epsilon = linear_schedule(1.0, 0.05, total // 2, step)
        actions = learner.act(eye[pos], np.ones(k, bool), epsilon)
        new_pos = np.clip(pos + np.where(actions == 1, 1, -1), 0, n - 1)
        t_in_episode += 1
        terminated, truncated = new_pos == n - 1, (t_in_episode >= 20) & (new_pos != n - 1)
        learner.update(
            Transition(
                eye[pos], actions, terminated.astype(np.float32), eye[new_pos], terminated, truncated, np.ones(k, bool)
            ),
            step,
        )
        done = terminated | truncated
        pos, t_in_episode = np.where(done, 0, new_pos), np.where(done, 0, t_in_episode)

    q = np.stack([learner.q_values(np.stack([eye[s]] * k)) for s in range(4)], axis=1)  # [K, 4, 2]
    expected = np.array([gamma**3, gamma**2, gamma, 1.0])  # 0.729, 0.81, 0.9, 1
    learned = (q.argmax(-1) == 1).all(axis=1) & (np.abs(q[..., 1] - expected) <= 0.1).all(axis=1)
    assert learned.sum() >= 3, q


def test_loading_bad_tensors_names_the_tensor():
    learner = dqn(hidden=[8])
    tensors = learner.agent_tensors(0)
    with pytest.raises(ValueError, match=r"'q.layers.0.weight' has shape \[8, 5\], expected \[8, 4\]"):
        learner.load_agent_tensors(0, {**tensors, "q.layers.0.weight": np.zeros((8, 5), np.float32)})
    del tensors["target.layers.1.bias"]
    with pytest.raises(ValueError, match="'target.layers.1.bias' is missing"):
        learner.load_agent_tensors(0, tensors)
    # Only q.* given (e.g. a hand-made network): the target becomes a copy of it.
    online_only = {name: t for name, t in learner.agent_tensors(0).items() if name.startswith("q.")}
    learner.load_agent_tensors(1, online_only)
    assert np.array_equal(learner.agent_tensors(1)["target.layers.0.weight"], online_only["q.layers.0.weight"])


@pytest.mark.parametrize("share_parameters", [False, True])
def test_greedy_actions_are_torchs_argmax_ties_included(share_parameters):
    """On the CPU the greedy action is first computed in numpy; it must be exactly torch's argmax,
    including near-ties (there torch decides) and exact ties (all-zero output layer: action 0)."""
    learner = dqn(num_agents=3, share_parameters=share_parameters, hidden=[16])
    rng = np.random.default_rng(0)

    def torch_argmax(obs):
        with torch.no_grad():
            q = learner.q_network(learner._team_batch(torch.from_numpy(obs).unsqueeze(1)))
        return q.reshape(3, -1).argmax(dim=-1).numpy()

    for _ in range(200):
        obs = rng.random((3, D), dtype=np.float32)
        assert np.array_equal(learner.greedy(obs, np.ones(3, bool)), torch_argmax(obs))
    weight, bias = learner.q_network.layer(1)
    with torch.no_grad():
        weight.zero_()
        bias.zero_()  # every Q-value 0: a tie everywhere
    obs = rng.random((3, D), dtype=np.float32)
    assert learner.greedy(obs, np.ones(3, bool)).tolist() == [0, 0, 0]
    with torch.no_grad():
        bias[:, 1] = 1e-7  # action 1 ahead by less than numpy and torch may disagree: torch decides
    real = learner.q_network.predict_numpy
    # A numpy that disagrees within the margin (its actions reversed: action 2 ahead): not to be trusted.
    learner.q_network.predict_numpy = lambda x, members=None: real(x, members)[..., ::-1].copy()
    assert learner.greedy(obs, np.ones(3, bool)).tolist() == torch_argmax(obs).tolist() == [1, 1, 1]
