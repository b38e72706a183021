"""The DQN side of the second edition's exchange methods (#24): shared experience
(``transfer.exchange=experience``) and parameter sharing with an agent-id input
(``agent.agent_id_input``). Worked cases on K = 2 agents in R = 2 replicas, each engine against
``dqn_reference.reference_update`` and against plain autograd, the transfer mapping of the ``agent_id``
segment, the config refusals and an exact resume."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from conftest import agent_meta, checked
from dqn_reference import reference_update
from test_dqn_update import ENGINES, Learner, learner_rows_per_member, sequential, stacked_grad
from test_train_cli import MAP, kill_and_resume

from dqn_transfer.agents import ReplayBatch, Transition
from dqn_transfer.agents.agent_id import AGENT_ID, agent_id_rows, append_agent_id
from dqn_transfer.agents.dqn_update import double_dqn_targets
from dqn_transfer.agents.shared_experience import batch_sources
from dqn_transfer.config import AgentConfig, ConfigError, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Exchange
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.transfer.mapping import plan_segment_mapping, transfer_dqn_tensors

LAYOUT = [("position", 5), ("treasures", 3)]
D, A, K, SEEDS = 8, 4, 2, [3, 4]
RTOL, ATOL = 1e-5, 1e-6


def filled(engine: str, batch_size: int = 4, experience_lambda: float | None = 1.0, **hp) -> Learner:
    """A learner of K = 2 agents in 2 replicas whose replay rows hold 6 transitions each, every reward
    the number of its row (agent k of replica r: row r * K + k), so a sample tells where it came from."""
    config = AgentConfig(hidden=[16], batch_size=batch_size, buffer_size=16, lr=1e-2, max_grad_norm=1e6, **hp)
    learner = ENGINES[engine](K, LAYOUT, A, config, seed=SEEDS)
    if experience_lambda is not None:
        learner.share_experience(experience_lambda)
    rng = np.random.default_rng(0)
    rows = learner.num_rows
    for _ in range(6):
        obs = rng.random((rows, D), dtype=np.float32)
        learner.replay.add(
            Transition(
                obs,
                rng.integers(0, A, rows),
                np.arange(rows, dtype=np.float32),
                rng.random((rows, D), dtype=np.float32),
                rng.random(rows) < 0.3,
                np.zeros(rows, bool),
                np.ones(rows, bool),
            )
        )
    return learner


def shared_batch(learner: Learner) -> tuple[ReplayBatch, np.ndarray]:
    """A shared-experience batch as ``gradient_step`` draws it (the networks' inputs), and its sample weights."""
    assert learner.shared_experience is not None
    batch = learner.replay.sample_rows(learner.shared_experience.sources)
    batch = batch._replace(obs=learner._network_inputs(batch.obs), next_obs=learner._network_inputs(batch.next_obs))
    return batch, learner.shared_experience.sample_weights(learner.replay.size > 0)


# ----------------------------------------------------------------------------------- shared experience


def test_each_agents_batch_is_half_its_own_and_half_its_team_mates_in_its_own_replica():
    """K = 2, a batch of 4: 2 own samples, then 2 of the team-mate, never of the other replica."""
    learner = filled("numpy")
    batch = learner.replay.sample_rows(learner.shared_experience.sources)
    assert batch.rewards.tolist() == [[0, 0, 1, 1], [1, 1, 0, 0], [2, 2, 3, 3], [3, 3, 2, 2]]
    stored = learner.replay.storage
    for row, source in np.ndindex(4, 4):  # each sample is one of its source row's transitions
        assert (stored[int(batch.rewards[row, source]), :6, :D] == batch.obs[row, source]).all(axis=1).any()


def test_batch_shares_round_down_for_team_mates_and_give_the_rest_to_the_agent():
    shares = batch_sources(3, 64)
    assert [(shares[0] == j).sum() for j in range(3)] == [22, 21, 21]
    assert shares[2, :22].tolist() == [2] * 22 and shares[2, 22:].tolist() == [0] * 21 + [1] * 21
    assert (batch_sources(3, 2) == np.arange(3)[:, None]).all()  # B < K: no team-mate gets a sample


def per_sample_losses(learner: Learner, batch: ReplayBatch, row: int) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Row's per-sample Huber losses by plain autograd on ``nn.Sequential`` copies of its member's
    current weights (Double DQN's target), and the parameters to differentiate."""
    member = row // K if learner.share_parameters else row
    sizes = learner.q_network.sizes
    online = sequential(sizes, learner.q_network.member_state(member))
    target = sequential(sizes, learner.target_network.member_state(member))
    obs, actions, rewards, next_obs, terminated = (torch.from_numpy(field[row]) for field in batch)
    with torch.no_grad():
        td_target = double_dqn_targets(rewards, online(next_obs), target(next_obs), terminated, learner.gamma)
    q_taken = online(obs).gather(-1, actions[:, None])[:, 0]
    return F.smooth_l1_loss(q_taken, td_target, reduction="none"), list(online.parameters())


def engine_gradients(learner: Learner, row: int) -> list[np.ndarray]:
    """Row's gradients as the engine left them, in ``nn.Sequential``'s parameter order and layout."""
    grads = [stacked_grad(learner, i)[row] for i in range(len(learner.q_network.shapes))]
    return [grad.T if i % 2 == 0 else grad for i, grad in enumerate(grads)]


@pytest.mark.parametrize("engine", ["numpy", "torch"])
@pytest.mark.parametrize("experience_lambda", [0.0, 0.5])
def test_the_loss_and_gradient_weigh_team_mates_samples_by_lambda(engine, experience_lambda):
    """lambda = 0: exactly the own samples' mean loss and its gradient; lambda = 0.5: by hand,
    (h_own1 + h_own2 + 0.5 h_mate1 + 0.5 h_mate2) / 3. Checked against autograd on the same weights."""
    learner = filled(engine, experience_lambda=experience_lambda)
    batch, sample_weights = shared_batch(learner)
    expected = []
    for row in range(learner.num_rows):
        losses, parameters = per_sample_losses(learner, batch, row)
        if experience_lambda == 0.0:
            loss = losses[:2].mean()
        else:
            loss = (losses[0] + losses[1] + 0.5 * losses[2] + 0.5 * losses[3]) / 3
        expected.append((loss.item(), torch.autograd.grad(loss, parameters)))
    stats = learner.train_on(batch, sample_weights)
    for row, (loss, grads) in enumerate(expected):
        assert stats.td_loss[row] == pytest.approx(loss, rel=RTOL)
        for got, want in zip(engine_gradients(learner, row), grads):
            np.testing.assert_allclose(got, want.numpy(), rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("engine", ["numpy", "torch"])
@pytest.mark.parametrize("share_parameters", [False, True], ids=["own_networks", "shared_with_agent_id"])
def test_an_engines_shared_experience_step_is_reference_update_with_sample_weights(engine, share_parameters):
    """Losses, mean Q and updated weights of one step equal ``reference_update`` run per network with
    the same per-sample weights (the clip active, so it is exercised too)."""
    learner = filled(engine, experience_lambda=0.5, share_parameters=share_parameters, agent_id_input=share_parameters)
    learner.max_grad_norm = 0.1
    batch, sample_weights = shared_batch(learner)
    sizes, per_member = learner.q_network.sizes, learner_rows_per_member(learner)
    loss_weights = torch.from_numpy(learner.loss_weights(learner.replay.size > 0))
    losses, q_means, updated = [], [], []
    for m in range(learner.num_members):
        rows = slice(m * per_member, (m + 1) * per_member)
        online = sequential(sizes, learner.q_network.member_state(m))
        target = sequential(sizes, learner.target_network.member_state(m))
        loss, q_mean = reference_update(
            online,
            target,
            torch.optim.Adam(online.parameters(), lr=learner.lr),
            tuple(torch.from_numpy(field[rows]) for field in batch),
            loss_weights[rows],
            gamma=learner.gamma,
            double=True,
            max_grad_norm=learner.max_grad_norm,
            sample_weights=torch.from_numpy(sample_weights[rows]),
        )
        losses.append(loss.numpy())
        q_means.append(q_mean.numpy())
        updated.append(
            {f"layers.{l // 2}.{('weight', 'bias')[l % 2]}": p.detach() for l, p in enumerate(online.parameters())}
        )
    stats = learner.train_on(batch, sample_weights)
    np.testing.assert_allclose(stats.td_loss, np.concatenate(losses), rtol=RTOL)
    np.testing.assert_allclose(stats.q_mean, np.concatenate(q_means), rtol=RTOL, atol=ATOL)
    for m, want in enumerate(updated):
        got = learner.q_network.member_state(m)
        for name in got:
            np.testing.assert_allclose(got[name], want[name].numpy(), rtol=RTOL, atol=ATOL, err_msg=name)


@pytest.mark.parametrize("share_parameters", [False, True], ids=["own_networks", "shared_with_agent_id"])
def test_numpy_and_torch_agree_on_a_shared_experience_step(share_parameters):
    """Same weights, same replay and sampling stream: one ``gradient_step`` of each engine."""
    hp = dict(experience_lambda=0.5, share_parameters=share_parameters, agent_id_input=share_parameters)
    numpy_learner, torch_learner = filled("numpy", **hp), filled("torch", **hp)
    for i in range(numpy_learner.num_rows):
        torch_learner.load_agent_tensors(i, numpy_learner.agent_tensors(i))
    stats = [learner.gradient_step() for learner in (numpy_learner, torch_learner)]
    np.testing.assert_allclose(stats[0].td_loss, stats[1].td_loss, rtol=RTOL)
    for i in range(numpy_learner.num_rows):
        a, b = numpy_learner.agent_tensors(i), torch_learner.agent_tensors(i)
        for name in a:
            np.testing.assert_allclose(a[name], b[name], rtol=RTOL, atol=ATOL, err_msg=name)


# -------------------------------------------------------------------------------------------- agent id


def test_agent_id_columns_are_each_agents_one_hot_in_every_replica():
    ids = agent_id_rows(6, 3)  # 2 replicas of 3 agents
    inputs = append_agent_id(np.zeros((6, 4, D), dtype=np.float32), ids)
    assert inputs.shape == (6, 4, D + 3)
    for r, k in np.ndindex(2, 3):
        assert (inputs[r * 3 + k, :, D:] == np.eye(3)[k]).all()

    learner = ENGINES["numpy"](
        3, LAYOUT, A, AgentConfig(hidden=[8], share_parameters=True, agent_id_input=True), seed=SEEDS
    )
    assert learner.obs_layout == [*LAYOUT, (AGENT_ID, 3)] and learner.obs_dim == D + 3
    assert learner.replay.obs_dim == D  # the replay keeps the game's observations
    obs = np.tile(np.random.default_rng(1).random((1, D), dtype=np.float32), (6, 1))  # all see the same
    q_values = learner.q_values(obs)
    for r in range(2):
        network = sequential(learner.q_network.sizes, learner.q_network.member_state(r))
        expected = network(torch.from_numpy(np.concatenate([obs[:3], np.eye(3, dtype=np.float32)], axis=1)))
        np.testing.assert_allclose(q_values[3 * r : 3 * r + 3], expected.detach().numpy(), rtol=RTOL, atol=ATOL)
        np.testing.assert_array_equal(learner.replica(r).q_values(obs[:3]), q_values[3 * r : 3 * r + 3])
    assert not np.allclose(q_values[0], q_values[1])  # the same observation, told apart by the id


def test_the_agent_id_segment_maps_by_index_and_a_source_without_it_reads_no_id():
    rng = np.random.default_rng(0)
    source_layout = [("position", 5), (AGENT_ID, 2)]
    tensors = {"q.layers.0.weight": rng.random((4, 7), dtype=np.float32), "q.layers.0.bias": np.zeros(4, np.float32)}
    tensors |= {"q.layers.1.weight": rng.random((A, 4), dtype=np.float32), "q.layers.1.bias": np.zeros(A, np.float32)}
    grown = transfer_dqn_tensors(tensors, source_layout, [("position", 5), (AGENT_ID, 3)], [4], A)
    weight = grown["q.layers.0.weight"]
    np.testing.assert_array_equal(weight[:, :7], tensors["q.layers.0.weight"])  # agents 0 and 1 keep theirs
    assert not weight[:, 7].any()  # the new agent's column reads nothing
    shrunk = plan_segment_mapping(source_layout, [("position", 5), (AGENT_ID, 1)])
    assert [seg.name for seg in shrunk.shared] == ["position", AGENT_ID] and not shrunk.dropped
    plain = {**tensors, "q.layers.0.weight": tensors["q.layers.0.weight"][:, :5]}
    added = transfer_dqn_tensors(plain, [("position", 5)], source_layout, [4], A)
    assert not added["q.layers.0.weight"][:, 5:].any()  # a new segment: zero input weights


# ------------------------------------------------------------------------------------------ the config


@pytest.mark.parametrize(
    ("agent", "transfer", "message"),
    [
        (dict(agent_id_input=True), {}, "agent_id_input=true .* needs agent.share_parameters=true"),
        (dict(algorithm=Algorithm.qlearning, lr=0.1, agent_id_input=True), {}, "agent_id_input=true .* a DQN learner"),
        (dict(algorithm=Algorithm.sarsa, lr=0.1), dict(exchange=Exchange.experience), "it needs a DQN learner"),
        ({}, dict(experience_lambda=0.5), "experience_lambda=0.5 .* needs transfer.exchange=experience"),
        ({}, dict(exchange=Exchange.experience, experience_lambda=-1.0), "must be >= 0 and finite"),
    ],
)
def test_refused_settings(agent, transfer, message):
    with pytest.raises(ConfigError, match=message):
        checked(TrainConfig(agent=AgentConfig(**agent), transfer=TransferConfig(**transfer)))


def test_accepted_settings():
    checked(TrainConfig(agent=AgentConfig(share_parameters=True, agent_id_input=True)))
    checked(TrainConfig(transfer=TransferConfig(exchange=Exchange.experience, experience_lambda=0.0)))


# ---------------------------------------------------------------------------------------------- resume


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_a_killed_run_with_shared_experience_and_agent_ids_resumes_exactly(tmp_path, monkeypatch):
    """A shared network with agent ids, trained on shared experience, killed after a checkpoint and
    resumed: the same evaluations and bit-identical weights as the uninterrupted run."""

    def config(resume: bool = False) -> TrainConfig:
        return TrainConfig(
            env=EnvConfig(layout=MAP),
            seed=0,
            total_steps=160,
            eval_every=40,
            eval_episodes=1,
            checkpoint_every=30,
            progress=False,
            resume=resume,
            agent=AgentConfig(
                hidden=[16], batch_size=8, learning_starts=30, share_parameters=True, agent_id_input=True
            ),
            transfer=TransferConfig(exchange=Exchange.experience, experience_lambda=0.5),
        )

    resumed, reference = kill_and_resume(tmp_path, monkeypatch, config, dies=lambda trainer: trainer.step > 60)
    assert resumed == reference
    metas = [agent_meta(tmp_path / name / "checkpoints" / "agent_1.safetensors") for name in ("killed", "reference")]
    assert metas[0]["digest"] == metas[1]["digest"]  # bit-identical weights
    assert metas[0]["obs_layout"][-1] == [AGENT_ID, 2]


def test_the_replay_default_sample_is_unchanged_by_sample_rows():
    """``sample`` draws as before: ``sample_rows`` of each row's own index is the same batch."""
    a, b = (filled("numpy", experience_lambda=None) for _ in range(2))
    own = np.repeat(np.arange(a.num_rows)[:, None], 4, axis=1)
    for x, y in zip(a.replay.sample(4), b.replay.sample_rows(own)):
        np.testing.assert_array_equal(x, y)
