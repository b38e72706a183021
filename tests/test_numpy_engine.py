"""agent.engine=numpy: the torch engine's updates to float32 rounding, independent replicas, no torch imported."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dqn_transfer import enums
from dqn_transfer.agents import DQNLearner, Transition, make_replicas
from dqn_transfer.agents.numpy_dqn import NumpyDQNLearner
from dqn_transfer.config import AgentConfig, ConfigError, TrainConfig, validate
from dqn_transfer.enums import Algorithm, Device, Engine, Mixer, Mode
from dqn_transfer.envs.settings import EnvConfig

LAYOUT = [("position", 5), ("treasures", 2)]
D, A = 7, 4


def transitions(num_rows: int, n: int, seed: int = 0) -> list[Transition]:
    rng = np.random.default_rng(seed)
    return [
        Transition(
            rng.random((num_rows, D), dtype=np.float32),
            rng.integers(0, A, num_rows),
            rng.normal(size=num_rows).astype(np.float32),
            rng.random((num_rows, D), dtype=np.float32),
            rng.random(num_rows) < 0.2,
            np.zeros(num_rows, bool),
            rng.random(num_rows) < 0.9,
        )
        for _ in range(n)
    ]


def agent(**kwargs) -> AgentConfig:
    return AgentConfig(
        **{
            **dict(
                algorithm=Algorithm.double_dqn,
                hidden=[16, 16],
                batch_size=8,
                buffer_size=64,
                learning_starts=4,
                lr=1e-2,
                target_update=5,
                tau=0.5,
            ),
            **kwargs,
        }
    )


def engines(num_agents: int, **kwargs) -> tuple[DQNLearner, NumpyDQNLearner]:
    """A torch and a numpy learner with the torch one's initial weights (the numpy engine draws its own)."""
    hp = agent(**kwargs)
    torch_learner = DQNLearner(num_agents, LAYOUT, A, hp, seed=3)
    numpy_learner = NumpyDQNLearner(num_agents, LAYOUT, A, hp, seed=3)
    for i in range(num_agents):
        numpy_learner.load_agent_tensors(i, torch_learner.agent_tensors(i))
    return torch_learner, numpy_learner


@pytest.mark.parametrize(
    "setting",
    [
        dict(algorithm=Algorithm.dqn),
        dict(),
        dict(share_parameters=True),
        dict(max_grad_norm=0.05),
        dict(mixer=Mixer.vdn),
    ],
)
def test_numpy_updates_are_the_torch_engines_to_float32_rounding(setting):
    """Same weights, same transitions, same replay draws: 40 updates later the networks, targets, Adam
    moments and statistics agree to float32 rounding (they are computed by other kernels)."""
    torch_learner, numpy_learner = engines(3, **setting)
    for step, t in enumerate(transitions(3, 40), start=1):
        stats = torch_learner.update(t, step), numpy_learner.update(t, step)
        np.testing.assert_allclose(stats[1].td_loss, stats[0].td_loss, rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(stats[1].q_mean, stats[0].q_mean, rtol=1e-4, atol=1e-5)
    assert numpy_learner.num_gradient_steps == torch_learner.num_gradient_steps == 36
    for i in range(3):
        got, want = numpy_learner.agent_tensors(i), torch_learner.agent_tensors(i)
        for name in want:
            np.testing.assert_allclose(got[name], want[name], rtol=1e-4, atol=1e-5, err_msg=name)
    arrays = torch_learner.training_state()[0], numpy_learner.training_state()[0]
    for name in arrays[0]:
        np.testing.assert_allclose(arrays[1][name], arrays[0][name], rtol=1e-3, atol=1e-7, err_msg=name)


def test_clipping_and_freezing_act_like_the_torch_engine():
    torch_learner, numpy_learner = engines(2, max_grad_norm=0.01)
    for learner in (torch_learner, numpy_learner):
        learner.freeze([0])
    before = numpy_learner.agent_tensors(0)
    for step, t in enumerate(transitions(2, 20, seed=1), start=1):
        torch_learner.update(t, step), numpy_learner.update(t, step)
    after = numpy_learner.agent_tensors(0)
    assert np.array_equal(after["q.layers.0.weight"], before["q.layers.0.weight"])  # frozen
    assert not np.array_equal(after["q.layers.1.weight"], before["q.layers.1.weight"])
    want = torch_learner.agent_tensors(0)
    for name in want:
        np.testing.assert_allclose(after[name], want[name], rtol=1e-4, atol=1e-6, err_msg=name)


def test_numpy_replicas_are_their_lone_learners_bit_for_bit():
    hp = agent(algorithm=Algorithm.dqn)
    joint = make_replicas(dataclasses.replace(hp, engine=Engine.numpy), 2, LAYOUT, A, seeds=[5, 6])
    lone = make_replicas(dataclasses.replace(hp, engine=Engine.numpy), 2, LAYOUT, A, seeds=[6])
    mine, other = transitions(2, 30, seed=2), transitions(2, 30, seed=3)
    for step, (a, b) in enumerate(zip(other, mine), start=1):
        actions = joint.act(np.concatenate([a.obs, b.obs]), np.ones(4, bool), 0.3)
        assert np.array_equal(actions[2:], lone.act(b.obs, np.ones(2, bool), 0.3))
        joint.update(Transition(*(np.concatenate([x, y]) for x, y in zip(a, b))), step)
        lone.update(b, step)
    for i in range(2):
        got, want = joint.replica(1).agent_tensors(i), lone.agent_tensors(i)
        assert all(np.array_equal(got[name], want[name]) for name in want)


def test_numpy_resume_continues_bit_for_bit():
    hp = dataclasses.replace(agent(), engine=Engine.numpy)
    steps = transitions(2, 40, seed=4)
    a, b = (make_replicas(hp, 2, LAYOUT, A, seeds=[1]) for _ in range(2))
    for step, t in enumerate(steps[:20], start=1):
        a.act(t.obs, t.live, 0.5), a.update(t, step)
    for i in range(2):
        b.load_agent_tensors(i, a.agent_tensors(i))
    b.load_training_state(*a.training_state())
    for step, t in enumerate(steps[20:], start=21):
        assert np.array_equal(a.act(t.obs, t.live, 0.5), b.act(t.obs, t.live, 0.5))
        a.update(t, step), b.update(t, step)
    for i in range(2):
        assert all(np.array_equal(a.agent_tensors(i)[n], t) for n, t in b.agent_tensors(i).items())


def test_numpy_engine_on_cuda_is_refused():
    cfg = TrainConfig(agent=AgentConfig(engine=Engine.numpy), device=Device.cuda)
    with pytest.raises(ConfigError, match="agent.engine=numpy runs on the CPU"):
        validate(cfg)


def test_a_loss_the_numpy_engine_does_not_implement_is_refused_in_one_line_naming_torch(monkeypatch):
    """Today the numpy engine implements every loss (DQN, Double DQN, VDN); a new one is written for torch
    first. Here VDN stands in for such a loss: refused on numpy, and the message says what to use."""
    cooperative = EnvConfig(mode=Mode.cooperative)
    cfg = TrainConfig(env=cooperative, agent=AgentConfig(engine=Engine.numpy, mixer=Mixer.vdn))
    validate(cfg)
    monkeypatch.setattr(enums, "NUMPY_MIXERS", (Mixer.none,))
    with pytest.raises(ConfigError) as refusal:
        validate(cfg)
    message = str(refusal.value)
    assert "\n" not in message and message.endswith("use agent.engine=torch")
    assert "agent.mixer=vdn" in message


@pytest.mark.parametrize("overrides", [["agent=dqn", "agent.engine=numpy"], ["agent=sarsa"]])
def test_a_numpy_or_tabular_run_never_imports_torch(tmp_path: Path, overrides):
    """The point of the engine: start-up without torch's seconds of imports (and checkpoints, TensorBoard
    and resume state written without it)."""
    script = (
        "import sys, runpy\n"
        f"sys.argv = ['train.py', *{overrides!r}, 'total_steps=60', 'eval_every=30', 'eval_episodes=1',"
        f" 'progress=false', 'agent.learning_starts=10', 'hydra.run.dir={tmp_path / 'run'}']\n"
        "try:\n    runpy.run_module('dqn_transfer.cli.train', run_name='__main__')\n"
        "except SystemExit as exit:\n    assert not exit.code, exit.code\n"
        "print('TORCH' if 'torch' in sys.modules else 'NO TORCH')\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == "NO TORCH"
    meta = json.loads((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()[-1])
    assert meta["step"] == 60
