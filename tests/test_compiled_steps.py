"""The compiled steps (``training/tabular_steps.py``, ``training/dqn_steps.py``) against the loop's Python
steps: the same run bit for bit -- evaluations, tables or weights, visits, entry order, replay, Adam's
moments, random streams, counters, episode records and the training curves' points -- in the cases
that exercise their parts (chest ties, the coordinator, team rewards, a view, Q-learning's max, DQN's
and Double DQN's targets, agent ids, both DQN engines, replicas on several maps, a replay that wraps,
episodes that end on every step)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_replicas import DQN, SARSA, assert_same_run, config

from dqn_transfer.agents.random_streams import draw_uniforms, stream_keys, uniforms
from dqn_transfer.enums import Algorithm, Engine
from dqn_transfer.training import trainer as trainer_module
from dqn_transfer.training.loop_kernels import UpdateWindow
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

CASES = {
    "sarsa_deliberative_replicas": dict(agent=SARSA, seeds=2, maps=2, env=dict(mode="deliberative")),
    "qlearning_team_view": dict(
        agent=dataclasses.replace(SARSA, algorithm=Algorithm.qlearning),
        seeds=3,
        env=dict(mode="competitive", reward_mode="team", view_radius=1, step_reward=-0.37),
    ),
    "sarsa_coords_short_episodes": dict(agent=SARSA, seeds=2, env=dict(obs_encoding="coords", max_steps=3)),
    "double_dqn_replicas_wrapping_replay": dict(
        agent=dataclasses.replace(DQN, buffer_size=150), seeds=2, maps=2, env=dict(mode="deliberative")
    ),
    "dqn_team_agent_ids_short_episodes": dict(
        agent=dataclasses.replace(
            DQN, algorithm=Algorithm.dqn, share_parameters=True, agent_id_input=True, train_freq=3
        ),
        seeds=2,
        env=dict(mode="competitive", reward_mode="team", max_steps=3),
    ),
    "double_dqn_torch_engine": dict(agent=dataclasses.replace(DQN, engine=Engine.torch), seeds=1, env=dict()),
}


def run(tmp_path, name: str, compiled: bool, monkeypatch) -> object:
    case = CASES[name]
    train = config(case["agent"], seeds=case["seeds"], maps=case.get("maps", 1), total_steps=700, checkpoint_every=350)
    train = dataclasses.replace(train, env=dataclasses.replace(train.env, **case["env"]), logger=["csv"])
    if not compiled:
        monkeypatch.setattr(trainer_module, "compiled_steps", lambda *args: None)
    used = []
    original = trainer_module.compiled_steps
    monkeypatch.setattr(trainer_module, "compiled_steps", lambda *args: used.append(original(*args)) or used[-1])
    trainer = Trainer(plan_run(train), tmp_path / ("compiled" if compiled else "python"))
    trainer.run()
    assert (used[0] is not None) == compiled
    monkeypatch.undo()
    return tmp_path / ("compiled" if compiled else "python")


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_compiled_steps_make_the_python_steps_run(tmp_path, monkeypatch, name):
    python = run(tmp_path, name, False, monkeypatch)
    compiled = run(tmp_path, name, True, monkeypatch)
    replicas = sorted(p.name for p in python.iterdir() if (p / "checkpoints").is_dir()) or ["."]
    for replica in replicas:
        assert_same_run(python / replica, compiled / replica)
        curves_a, curves_b = (
            [line for line in (root / replica / "scalars.csv").read_text().splitlines() if ",train/sps," not in line]
            for root in (python, compiled)
        )  # step,tag,value rows; the speed is a clock's
        assert len(curves_a) > 100 and curves_a == curves_b


def test_the_update_window_means_are_numpys_nanmean():
    rng = np.random.default_rng(0)
    steps = rng.normal(size=(30, 2, 5))
    idle = rng.random((30, 5)) < 0.4  # rows without an update on a step: both values NaN
    steps[:, 0][idle] = np.nan
    steps[:, 1][idle] = np.nan
    steps[:, :, 4] = np.nan  # a row never updated
    steps[0, 1, 0] = -0.0
    window = UpdateWindow(5)
    for td_loss, q_mean in steps:
        window.add(td_loss, q_mean)
    means = window.means()
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        expected = np.nanmean(steps, axis=0)
    np.testing.assert_array_equal(np.stack(means), expected)
    assert window.means() is None  # the window starts again


def test_the_compiled_draw_is_the_array_draw():
    keys = stream_keys(np.arange(40), 2, np.arange(40) % 4)
    counters = np.random.default_rng(1).integers(0, 2**40, size=40)
    expected, out = uniforms(keys, counters, 3), np.empty(3)
    for key, counter, row in zip(keys, counters, expected):
        draw_uniforms(key, counter, out)
        assert out.tobytes() == row.tobytes()
