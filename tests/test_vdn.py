"""VDN (``agent.mixer=vdn``, Sunehag et al. 2018): the team's TD target worked out by hand on a tiny batch
with a finished agent, each engine's gradients and steps against plain autograd of the summed loss
(``dqn_update.reference_vdn_update`` on ``nn.Sequential`` copies), the joint replay, the config
refusals, an exact resume, and the command line end to end."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import agent_meta, checked, read_metrics, run_many
from dqn_reference import reference_vdn_update
from safetensors.numpy import load_file
from test_dqn_update import ENGINES, Learner, linear_layers, sequential, stacked_grad
from test_train_cli import MAP, kill_and_resume

from dqn_transfer.agents import ReplayBatch, ReplayBuffer, Transition
from dqn_transfer.config import AgentConfig, ConfigError, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Exchange, Mixer, Mode, RewardMode
from dqn_transfer.envs.settings import EnvConfig

LAYOUT = [("position", 5), ("treasures", 3)]
D, A, K, SEEDS, B = 8, 4, 2, [3, 4], 16
RTOL, ATOL = 1e-5, 1e-6
TINY_GRADIENT = 1e-6  # within a hundred times Adam's eps: rounding may change the step


def vdn_learner(engine: str, replicas: int = 1, **hp) -> Learner:
    config = AgentConfig(
        **{"mixer": Mixer.vdn, "hidden": [16, 16], "batch_size": B, "buffer_size": 32, "lr": 1e-2, **hp}
    )
    return ENGINES[engine](K, LAYOUT, A, config, seed=SEEDS[:replicas])


def store_one_step(learner: Learner) -> None:
    """One joint step of every agent in the replay (what makes every row's loss count)."""
    rows = learner.num_rows
    zeros = np.zeros((rows, D), dtype=np.float32)
    empty = np.zeros(rows, dtype=bool)
    learner.replay.add(Transition(zeros, np.zeros(rows, np.int64), empty, zeros, empty, empty, ~empty))


# ------------------------------------------------------------------------------ the target by hand

ONLINE_BIAS = [[1.0, 2.0, 3.0, 4.0], [0.5, -1.0, 2.0, 0.0]]  # agent k's Q-values, whatever it observes
TARGET_BIAS = [[2.0, 0.0, 1.0, 5.0], [4.0, 3.0, 7.0, 1.0]]


def constant_q(learner: Learner) -> None:
    """Every weight 0 and the output biases above: ``Q_k(o, a)`` is ``ONLINE_BIAS[k][a]`` for any ``o``."""
    for network, biases in ((learner.q_network, ONLINE_BIAS), (learner.target_network, TARGET_BIAS)):
        for k, bias in enumerate(biases):
            state = {name: np.zeros_like(t) for name, t in network.member_state(k).items()}
            state[f"layers.{network.num_layers - 1}.bias"] = np.array(bias, dtype=np.float32)
            network.load_member_state(k, state)


@pytest.mark.parametrize("engine", sorted(ENGINES))
@pytest.mark.parametrize("algorithm", [Algorithm.dqn, Algorithm.double_dqn])
def test_the_team_target_and_gradient_by_hand_with_a_finished_agent(engine, algorithm):
    """gamma = 0.5, two joint steps. Step 0: agent 0 plays action 1 (reward -1, goes on), agent 1 takes a
    chest with action 2 (reward 100, terminated). Step 1: agent 0 plays action 3 (reward -1, truncated:
    it still bootstraps), agent 1 is finished (not live; its row holds action 0, reward 0).

    Agent 0's next value is 5 either way (DQN: max of [2, 0, 1, 5]; Double DQN: the online argmax 3 of
    [1, 2, 3, 4] scored by the target: 5). Agent 1's (7) is cut by its termination, then by its absence.
      step 0: Q_tot = Q_0(1) + Q_1(2) = 2 + 2 = 4;  y = (-1 + 100) + 0.5 * 5 = 101.5;  error -97.5
      step 1: Q_tot = Q_0(3) = 4;                    y = -1 + 0.5 * 5 = 1.5;           error 2.5
    Loss: the mean Huber of the errors, both beyond 1: ((97.5 - 0.5) + (2.5 - 0.5)) / 2 = 49.5.
    d loss / d Q_tot = clip(error, -1, 1) / 2 = [-0.5, 0.5]: agent 0's output bias gets -0.5 on action 1
    and 0.5 on action 3; agent 1's gets -0.5 on action 2 only (it was not live in step 1)."""
    learner = vdn_learner(engine, hidden=[4], gamma=0.5, algorithm=algorithm, max_grad_norm=1e6)
    constant_q(learner)
    store_one_step(learner)
    obs = np.zeros((K, 2, D), dtype=np.float32)
    batch = ReplayBatch(
        obs,
        np.array([[1, 3], [2, 0]]),
        np.array([[-1.0, -1.0], [100.0, 0.0]], dtype=np.float32),
        obs,
        np.array([[0.0, 0.0], [1.0, 0.0]], dtype=np.float32),
    )
    live = np.array([[1.0, 1.0], [1.0, 0.0]], dtype=np.float32)
    stats = learner.train_on(batch, live=live)
    np.testing.assert_allclose(stats.td_loss, [49.5, 49.5])
    np.testing.assert_allclose(stats.q_mean, [3.0, 2.0])  # agent 0: (2 + 4) / 2; agent 1: step 0 only
    output_bias_grad = stacked_grad(learner, 3)
    np.testing.assert_allclose(output_bias_grad, [[0.0, -0.5, 0.0, 0.5], [0.0, 0.0, -0.5, 0.0]])


# ------------------------------------------------------------------------------ against autograd


def random_team_batch(rows: int, seed: int) -> tuple[ReplayBatch, np.ndarray]:
    """Random joint steps, a third terminated, a quarter of the agents' rows not live (never all of a
    column: some agent acts in every step)."""
    rng = np.random.default_rng(seed)
    batch = ReplayBatch(
        rng.random((rows, B, D), dtype=np.float32),
        rng.integers(0, A, (rows, B)),
        (3.0 * rng.normal(size=(rows, B))).astype(np.float32),
        rng.random((rows, B, D), dtype=np.float32),
        (rng.random((rows, B)) < 0.3).astype(np.float32),
    )
    live = (rng.random((rows, B)) < 0.75).astype(np.float32)
    live[0::K][live.reshape(-1, K, B).sum(1) == 0] = 1.0  # agent 0 acts where nobody else does
    return batch, live


@pytest.mark.parametrize("engine", sorted(ENGINES))
@pytest.mark.parametrize("algorithm", [Algorithm.dqn, Algorithm.double_dqn])
@pytest.mark.parametrize("share_parameters", [False, True], ids=["own_networks", "shared_network"])
@pytest.mark.parametrize(("max_grad_norm", "clip_active"), [(1e-3, True), (1e3, False)])
def test_each_engines_vdn_step_is_autograd_of_the_summed_loss(
    engine, algorithm, share_parameters, max_grad_norm, clip_active
):
    """Two replicas of two agents, three steps: each network's gradient, clipped norm and new weights, the
    team's loss and each agent's mean Q(s, a) equal ``reference_vdn_update`` on plain ``nn.Sequential``
    copies (one per agent, or one per replica shared by its agents)."""
    learner = vdn_learner(
        engine, replicas=2, algorithm=algorithm, share_parameters=share_parameters, max_grad_norm=max_grad_norm
    )
    # A target network unlike the online one (otherwise Double DQN's target would be DQN's).
    other = vdn_learner(engine, replicas=2, share_parameters=share_parameters)
    learner.target_network.update_from(other.q_network, tau=1.0)
    store_one_step(learner)
    sizes, members = learner.q_network.sizes, learner.members_per_replica
    online = [sequential(sizes, learner.q_network.member_state(m)) for m in range(learner.num_members)]
    target = [sequential(sizes, learner.target_network.member_state(m)) for m in range(learner.num_members)]
    optimizers = [torch.optim.Adam(network.parameters(), lr=learner.lr) for network in online]
    # What the engines promise: the same gradients to float rounding, hence the same Adam steps, except for
    # an element whose gradient is so small that Adam's eps (1e-8) is not negligible beside it: there,
    # lr * m / (sqrt(v) + eps) turns rounding into another step of at most lr (the CPU's BLAS kernel decides
    # which). So each step starts the references from the engine's weights, and such an element is held to lr.
    for step in range(3):
        with torch.no_grad():
            for m, network in enumerate(online):
                network.load_state_dict(sequential(sizes, learner.q_network.member_state(m)).state_dict())
        batch, live = random_team_batch(learner.num_rows, seed=step)
        stats = learner.train_on(batch, live=live)
        for r in range(2):
            rows, team = slice(r * K, (r + 1) * K), slice(r * members, (r + 1) * members)
            agents = [m % members for m in range(K)]  # each agent's network within the replica's
            loss, q_mean = reference_vdn_update(
                [online[team][a] for a in agents],
                [target[team][a] for a in agents],
                optimizers[team],
                tuple(torch.from_numpy(field[rows]) for field in batch),
                torch.from_numpy(live[rows]),
                gamma=learner.gamma,
                double=algorithm is Algorithm.double_dqn,
                max_grad_norm=learner.max_grad_norm,
            )
            np.testing.assert_allclose(stats.td_loss[rows], [float(loss)] * K, rtol=RTOL)
            np.testing.assert_allclose(stats.q_mean[rows], q_mean.numpy(), rtol=RTOL, atol=ATOL)
        for m, network in enumerate(online):
            norm = torch.cat([p.grad.reshape(-1) for p in network.parameters()]).norm()
            assert (float(norm) == pytest.approx(max_grad_norm, rel=1e-4)) if clip_active else norm < max_grad_norm
            weights = learner.q_network.member_state(m)
            for l, layer in enumerate(linear_layers(network)):
                grad_w, grad_b = stacked_grad(learner, 2 * l)[m], stacked_grad(learner, 2 * l + 1)[m]
                np.testing.assert_allclose(np.asarray(grad_w).T, layer.weight.grad.numpy(), rtol=RTOL, atol=ATOL)
                np.testing.assert_allclose(np.asarray(grad_b), layer.bias.grad.numpy(), rtol=RTOL, atol=ATOL)
                for name, parameter in (("weight", layer.weight), ("bias", layer.bias)):
                    reference = parameter.detach().numpy()
                    tiny = np.abs(parameter.grad.numpy()) < TINY_GRADIENT
                    allowed = np.where(tiny, learner.lr, ATOL + RTOL * np.abs(reference))
                    assert np.all(np.abs(weights[f"layers.{l}.{name}"] - reference) <= allowed), (m, l, name)


def test_the_reference_is_the_gradient_of_the_summed_loss_written_out():
    """``reference_vdn_update`` itself, on constant networks (``constant_q``'s numbers as biases): the
    summed Huber loss of the worked case above, 49.5, and its gradient on the biases."""
    networks = [torch.nn.Linear(D, A) for _ in range(K)]
    targets = [torch.nn.Linear(D, A) for _ in range(K)]
    with torch.no_grad():
        for k in range(K):
            for net, bias in ((networks[k], ONLINE_BIAS[k]), (targets[k], TARGET_BIAS[k])):
                net.weight.zero_()
                net.bias.copy_(torch.tensor(bias))
    optimizers = [torch.optim.SGD(net.parameters(), lr=0.0) for net in networks]
    obs = torch.zeros(K, 2, D)
    batch = (
        obs,
        torch.tensor([[1, 3], [2, 0]]),
        torch.tensor([[-1.0, -1.0], [100.0, 0.0]]),
        obs,
        torch.tensor([[0.0, 0.0], [1.0, 0.0]]),
    )
    loss, q_mean = reference_vdn_update(
        networks,
        targets,
        optimizers,
        batch,
        torch.tensor([[1.0, 1.0], [1.0, 0.0]]),
        gamma=0.5,
        double=True,
        max_grad_norm=1e6,
    )
    assert float(loss) == 49.5
    assert q_mean.tolist() == [3.0, 2.0]
    assert networks[0].bias.grad.tolist() == [0.0, -0.5, 0.0, 0.5]
    assert networks[1].bias.grad.tolist() == [0.0, 0.0, -0.5, 0.0]


# ------------------------------------------------------------------------------------ joint replay


def test_a_joint_replay_keeps_the_teams_steps_aligned():
    """Two replicas of two agents. Step 1: every agent live. Step 2: replica 0's agent 1 is done (its row
    is stored, not live); replica 1 is all done (nothing stored). A sample draws the same slots for a
    replica's rows, with the live column as it was stored."""
    replay = ReplayBuffer(4, 8, 1, [np.random.default_rng(0), np.random.default_rng(1)], joint=True)
    obs = np.arange(4, dtype=np.float32)[:, None]
    rows = np.arange(4)
    replay.add(Transition(obs, rows, rows.astype(np.float32), obs, rows == 9, rows == 9, rows < 4))
    replay.add(Transition(obs + 10, rows, rows + 10.0, obs + 10, rows == 9, rows == 9, rows == 0))
    assert replay.size.tolist() == [2, 2, 1, 1]
    batch, live = replay.sample_joint(6)
    slot = batch.rewards >= 10  # step 2's samples
    np.testing.assert_array_equal(slot[0], slot[1])
    np.testing.assert_array_equal(slot[2:], False)
    np.testing.assert_array_equal(live[0], 1.0)
    np.testing.assert_array_equal(live[1], np.where(slot[1], 0.0, 1.0))
    np.testing.assert_array_equal(live[2:], 1.0)
    with pytest.raises(ValueError, match="joint replay"):
        replay.extend(0, obs[:1], rows[:1], obs[:1, 0], obs[:1], rows[:1] == 9)


# ------------------------------------------------------------------------------------ the schema


def vdn_config(**changes) -> TrainConfig:
    env = changes.pop("env", EnvConfig(mode=Mode.cooperative))
    return TrainConfig(env=env, agent=AgentConfig(mixer=Mixer.vdn, **changes.pop("agent", {})), **changes)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (
            vdn_config(agent={"algorithm": Algorithm.sarsa}),
            r"agent.mixer=vdn sums the agents' Q-networks: it needs a DQN learner \(agent=dqn .*\), not agent=sarsa",
        ),
        (vdn_config(env=EnvConfig()), "use mode=cooperative or mode=deliberative, not mode=competitive"),
        (
            vdn_config(env=EnvConfig(mode=Mode.cooperative, reward_mode=RewardMode.team)),
            "use env.reward_mode=individual",
        ),
        (vdn_config(transfer=TransferConfig(exchange=Exchange.shared_replay)), "transfer.exchange=shared_replay moves"),
        (vdn_config(transfer=TransferConfig(exchange=Exchange.experience)), "transfer.exchange=experience moves"),
    ],
    ids=["tabular", "competitive", "team_reward", "shared_replay", "experience"],
)
def test_vdn_refusals(config, message):
    with pytest.raises(ConfigError, match=message):
        checked(config)


def test_accepted_vdn_settings():
    checked(vdn_config(env=EnvConfig(mode=Mode.deliberative), agent={"share_parameters": True}))
    checked(vdn_config(transfer=TransferConfig(exchange=Exchange.best), agent={"engine": "torch"}))
    checked(vdn_config(env=EnvConfig(factory="dqn_transfer.envs.lbf:parallel_env")))  # another game's own rewards


# ------------------------------------------------------------------------------------------ resume


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_a_killed_vdn_run_resumes_exactly(tmp_path, monkeypatch):
    """Killed after a mid-episode checkpoint and resumed: the same evaluations and bit-identical weights."""

    def config(resume: bool = False) -> TrainConfig:
        return vdn_config(
            env=EnvConfig(layout=MAP, mode=Mode.cooperative),
            agent={"hidden": [16], "batch_size": 8, "learning_starts": 30},
            seed=0,
            total_steps=160,
            eval_every=40,
            eval_episodes=1,
            checkpoint_every=30,
            progress=False,
            resume=resume,
        )

    resumed, reference = kill_and_resume(tmp_path, monkeypatch, config, dies=lambda trainer: trainer.step > 60)
    assert resumed == reference
    for agent in ("agent_0", "agent_1"):
        metas = [
            agent_meta(tmp_path / name / "checkpoints" / f"{agent}.safetensors") for name in ("killed", "reference")
        ]
        assert metas[0]["digest"] == metas[1]["digest"]  # bit-identical weights


# ---------------------------------------------------------------------------------- command line


def test_train_py_with_vdn_end_to_end_and_refused_in_one_line(tmp_path):
    """``python train.py agent=double_dqn agent.mixer=vdn mode=cooperative`` trains and checkpoints the
    joint replay (its live column); ``mode=competitive`` is refused in one line, no traceback."""
    common = ("agent=double_dqn", "agent.mixer=vdn", "agent.learning_starts=50", "eval_every=150", "eval_episodes=2")
    trained, refused = run_many(
        [
            (tmp_path, (*common, "mode=cooperative", "total_steps=300"), tmp_path / "vdn"),
            (tmp_path, (*common, "mode=competitive", "total_steps=10"), tmp_path / "refused"),
        ],
        check=False,
    )
    trained.check()
    assert [record["step"] for record in read_metrics(trained.run_dir)] == [0, 150, 300]
    state = load_file(str(trained.run_dir / "checkpoints" / "training_state.safetensors"))
    live = state["learner/replay.live"]
    assert live.shape == (2, 300) and live.any(axis=0).all()  # every step stored for both agents, someone live
    assert refused.returncode != 0 and "Traceback" not in refused.output
    assert "agent.mixer=vdn trains the team on the sum of its rewards" in refused.stderr
