"""The PettingZoo and Gymnasium faces: API conformance, seeding, parameters, SB3 compatibility."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, render_test, seed_test

import dqn_transfer
from dqn_transfer.envs import TreasureHuntEnv, TreasureHuntParallelEnv, generate_layout, make_game
from dqn_transfer.envs.treasure_hunt import env as aec_env
from dqn_transfer.envs.treasure_hunt import parallel_env

MAP = dict(size=6, num_treasures=3, num_agents=3, complexity=0.1, map_seed=1)
VARIANT = dict(view_radius=1, obs_encoding="coords", reward_mode="team")


@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
@pytest.mark.parametrize("extra", [{}, VARIANT])
def test_pettingzoo_api(mode, extra):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the API tests report problems as warnings
        parallel_api_test(parallel_env(mode=mode, **MAP, **extra), num_cycles=100)
        api_test(aec_env(mode=mode, **MAP, **extra), num_cycles=100)


def test_parallel_env_spaces_and_metadata():
    env = TreasureHuntParallelEnv(mode="deliberative", view_radius=1, **MAP)
    assert env.metadata["name"] == "treasure_hunt_v0"
    assert env.possible_agents == ["agent_0", "agent_1", "agent_2"]
    space = env.observation_space("agent_1")
    assert space is env.observation_space("agent_1")
    assert space.shape == (36 + 3 + 3 + 27,) and space.dtype == np.float32
    assert (space.low == 0).all() and (space.high == 1).all()
    assert env.action_space("agent_0").n == 4
    obs, infos = env.reset(seed=0)
    assert all(space.contains(o) for o in obs.values()) and set(infos) == set(env.possible_agents)
    assert isinstance(env.game.obs_layout(), list)


def rollout(env, seed: int, steps: int = 300):
    """Fixed random joint actions through reset(seed) and auto-resets; the first joint action
    sends agents 0 and 1 into the same chest, a tie only the env's generator can break."""
    actions = np.random.default_rng(123).integers(0, 4, size=(steps, env.max_num_agents))
    actions[0] = [3, 2, 0]
    obs, _ = env.reset(seed=seed)
    trace = []
    for row in actions:
        if not env.agents:
            obs, _ = env.reset()
        obs, rew, term, trunc, _ = env.step({a: row[int(a[-1])] for a in env.agents})
        trace.append((sorted(rew.items()), [o.tolist() for o in obs.values()]))
    return trace


def test_reset_seed_makes_everything_reproducible():
    # a map full of chest ties: 3 agents, 2 chests in a 3 x 3 corner
    layout = "0T1\n.2.\nT..\n"
    a = rollout(parallel_env(layout=layout), seed=5)
    b = rollout(parallel_env(layout=layout), seed=5)
    assert a == b
    seeds = {str(rollout(parallel_env(layout=layout), seed=s, steps=40)) for s in range(12)}
    assert len(seeds) > 1  # the tie's winner depends on the seed


def test_aec_env_plays_the_parallel_game_agent_by_agent():
    """Agents take turns in index order, and a full turn of the AEC env is one joint step of the
    parallel env: after the same moves (everyone right, then everyone down) the agents stand where the
    parallel env puts them."""
    moves = [3, 3, 1, 1]
    aec, parallel = aec_env(**MAP), parallel_env(**MAP)
    aec.reset(seed=3)
    parallel.reset(seed=3)
    order = []
    for turn, agent in enumerate(aec.agent_iter(len(moves) * 3)):
        *_, terminated, truncated, _ = aec.last()
        order.append(agent)
        aec.step(None if terminated or truncated else moves[turn // 3])
    for move in moves:
        parallel.step({agent: move for agent in parallel.agents})
    assert order[:3] == ["agent_0", "agent_1", "agent_2"]
    np.testing.assert_array_equal(aec.unwrapped.game.positions, parallel.game.positions)


# ---------------------------------------------------------------- invalid parameters
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(mode="chaos"), "mode must be one of competitive, cooperative, deliberative"),
        (dict(reward_mode="shared"), "reward_mode must be one of individual, team"),
        (dict(obs_encoding="pixels"), "obs_encoding must be one of onehot, coords"),
        (dict(view_radius=-1), "view_radius must be an integer >= 0"),
        (dict(view_radius=1.5), "view_radius"),
        (dict(max_steps=0), "max_steps must be an integer >= 1"),
        (dict(size=1), "size must be >= 2"),
        (dict(num_agents=11), "num_agents must be between 1 and 10"),
        (dict(complexity=2.0), "complexity must be in"),
        (dict(render_mode="window"), "render_mode must be one of ansi, rgb_array, human"),
        (dict(step_reward=float("nan")), "step_reward must be finite"),
        (dict(treasure_reward="lots"), "treasure_reward must be a number"),
        (dict(layout="0T\n.a"), "unknown character 'a'"),
    ],
)
def test_invalid_env_kwargs_name_the_parameter(kwargs, match):
    for face in (TreasureHuntParallelEnv, TreasureHuntEnv):
        with pytest.raises(ValueError, match=match):
            face(**kwargs)


def test_invalid_actions():
    env = parallel_env(**MAP)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="no action for live agent agent_1"):
        env.step({"agent_0": 0, "agent_2": 0})
    with pytest.raises(ValueError, match="actions must be in 0..3"):
        env.step({"agent_0": 4, "agent_1": 0, "agent_2": 0})


def test_layout_overrides_generation_params_with_a_warning():
    with pytest.warns(UserWarning, match=r"size=6 \(layout: 3\)"):
        env = parallel_env(layout="0T1\n...\n...", size=6, num_treasures=1)
    assert env.possible_agents == ["agent_0", "agent_1"] and env.game.size == 3


# ---------------------------------------------------------------- the Gymnasium face
def test_import_registers_treasure_hunt_once():
    assert "TreasureHunt-v0" in gymnasium.registry
    import importlib

    importlib.reload(dqn_transfer)  # a second registration would warn/raise
    assert "TreasureHunt-v0" in gymnasium.registry


@pytest.mark.parametrize("extra", [{}, {"view_radius": 2, "render_mode": "rgb_array"}])
def test_gymnasium_check_env(extra):
    env = gymnasium.make("TreasureHunt-v0", **MAP, **extra)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    assert isinstance(env.unwrapped, TreasureHuntEnv)


def test_single_agent_mdp_is_agent_0_on_the_same_map():
    layout = "0...T\n.....\n..X..\n.....\n1...."
    env = gymnasium.make("TreasureHunt-v0", layout=layout, mode="deliberative", render_mode="ansi")
    obs, _ = env.reset(seed=0)
    assert env.unwrapped.obs_layout() == [("position", 25)]
    assert obs.shape == (25,) and obs[0] == 1.0
    total = 0.0
    for _ in range(4):
        obs, reward, terminated, truncated, info = env.step(3)  # right x 4 to the chest
        total += reward
    assert total == 97.0 and terminated and not truncated and info["treasures_collected"] == 1
    assert env.render().splitlines()[0] == "....t"  # agent 0 done, chest emptied
    multi = make_game(layout=layout)
    assert multi.num_agents == 2 and env.unwrapped.game.num_agents == 1


def test_gymnasium_truncates_at_max_steps():
    env = gymnasium.make("TreasureHunt-v0", layout="0.T\n...\n...", max_steps=3)
    env.reset(seed=0)
    flags = [env.step(0)[2:4] for _ in range(3)]  # up: off grid, stays
    assert flags == [(False, False), (False, False), (False, True)]


def test_stable_baselines3_dqn_runs():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import DQN

    env = gymnasium.make("TreasureHunt-v0", size=5, num_treasures=1, complexity=0.1)
    model = DQN(
        "MlpPolicy", env, learning_starts=50, buffer_size=1_000, batch_size=32, train_freq=4, seed=0, device="cpu"
    )
    model.learn(total_timesteps=300)
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(int(action))


def test_generated_map_matches_generate_layout():
    env = parallel_env(size=7, num_treasures=2, complexity=0.2, map_seed=4)
    assert env.game.map.layout == generate_layout(7, 2, complexity=0.2, seed=4)


def test_pettingzoo_render_and_seed_tests_pass():
    """PettingZoo's own render_test builds the env with render_mode="human" first, then every mode
    of its metadata; the seed tests play two envs seeded alike and compare everything."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        render_test(lambda render_mode=None: aec_env(render_mode=render_mode, **MAP))
        seed_test(lambda: aec_env(**MAP), num_cycles=100)
        parallel_seed_test(lambda: parallel_env(**MAP), num_cycles=100)


def test_human_mode_prints_the_text_frame_at_reset_and_every_step(capsys):
    layout = "0.T\n...\nX.."
    env = parallel_env(layout=layout, render_mode="human")
    env.reset(seed=0)
    env.step({"agent_0": 3})  # right: beside the chest
    assert env.render() is None
    frames = capsys.readouterr().out.split("\n\n")
    assert frames[:3] == [
        "0.T\n...\nX..\nstep 0/9  live agents: [0]  full chests: 1/1",
        ".0T\n...\nX..\nstep 1/9  live agents: [0]  full chests: 1/1",
        ".0T\n...\nX..\nstep 1/9  live agents: [0]  full chests: 1/1",
    ]
    single = gymnasium.make("TreasureHunt-v0", layout=layout, render_mode="human")
    single.reset(seed=0)
    single.step(3)
    single.step(3)  # into the chest: the agent is done, the chest emptied
    assert capsys.readouterr().out.split("\n\n")[2] == "..t\n...\nX..\nstep 2/9  live agents: []  full chests: 0/1"


def test_plain_id_is_not_a_one_step_task():
    """``gymnasium.make("TreasureHunt-v0")`` with no arguments: no single action from the start reaches
    a chest (map seed 0 started the agent beside one, so every library "solved" it at step 0), and the
    optimal return takes several moves."""
    env = gymnasium.make("TreasureHunt-v0")
    grid = env.unwrapped.game.map
    start = grid.starts[0]
    distances = grid.distances_from(start)
    nearest = min(int(distances[chest]) for chest in grid.chests if distances[chest] >= 0)
    assert nearest >= 3, f"the nearest chest is {nearest} move(s) from the start"
    for action in range(env.action_space.n):
        env.reset(seed=0)
        _, reward, terminated, _, _ = env.step(action)
        assert not (terminated and reward > 0), f"action {action} reaches a chest in one step"
    # A layout or a map seed given by the caller is played as given, with no warning.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert (
            gymnasium.make("TreasureHunt-v0", map_seed=0).unwrapped.game.map.starts[0]
            == (make_game(map_seed=0).map.starts[0])
        )
        gymnasium.make("TreasureHunt-v0", layout="0.T\n...\n..X")
