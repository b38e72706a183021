"""Games other than the treasure hunt (docs/your_own_environment.md): any PettingZoo ParallelEnv through
:class:`~dqn_transfer.envs.PettingZooGame`, Level-Based Foraging's adapter and its size-to-size transfer.

The env the project does not ship is ``tests/corridor_env.py``: two agents with different spaces, slips
drawn from the env's seeded generator, agents leaving early, truncation.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from conftest import agent_meta, compose_config, read_metrics, run_train, without_timing
from PIL import Image

from dqn_transfer.analysis.runs import load_config
from dqn_transfer.cli.play import main as play
from dqn_transfer.config import AgentConfig, ReplicasConfig, TrainConfig, TransferConfig
from dqn_transfer.envs import PettingZooGame, UnsupportedEnv
from dqn_transfer.envs.lbf import lbf_segments
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.evaluation.rollout import evaluate
from dqn_transfer.sharing.model_card import ExportError, export_team
from dqn_transfer.sharing.team import load_team
from dqn_transfer.sources.resolve import transfer_sources
from dqn_transfer.storage.checkpoint import CheckpointError, load_agent_checkpoint, load_training_state
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.plan import plan_run, treasure_hunt_settings
from dqn_transfer.training.trainer import train
from dqn_transfer.transfer.mapping import TransferError, segment_slices
from dqn_transfer.transfer.warm_start import check_same_game

CORRIDOR = "corridor_env:parallel_env"
LBF = "dqn_transfer.envs.lbf:parallel_env"
SPREAD = "mpe2.simple_spread_v3:parallel_env"
TESTS = Path(__file__).resolve().parent


def with_corridor(monkeypatch) -> None:
    """``corridor_env`` importable by the ``train.py`` processes a test starts."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")])))


def corridor(**kwargs) -> PettingZooGame:
    return PettingZooGame(CORRIDOR, kwargs)


# ------------------------------------------------------------------------------------ the adapter


def test_spaces_are_flattened_padded_and_actions_aliased():
    game = corridor(length=5)
    assert (game.num_agents, game.obs_dim, game.num_actions) == (2, 5, 3)
    assert game.obs_layout() == [("obs", 5)]
    obs = game.reset(np.random.default_rng(0))
    assert obs[0].tolist() == [1, 0, 0, 0, 0]  # walker: Discrete(5) one-hot of cell 0
    assert obs[1, 0] == 0.0 and 0.0 <= obs[1, 1] < 1.0 and obs[1, 2:].tolist() == [0, 0, 0]  # runner: Box(2), padded
    game.step(np.array([1, 2]))  # the runner has 2 actions: its action 2 is its action 0 (left)
    assert game.state_dict()["actions"] == [[1, 0]]


def test_agents_leave_early_and_the_episode_truncates():
    game = corridor(length=3, max_steps=4, slip=0.0)
    game.reset(np.random.default_rng(0))
    first = game.step(np.array([2, 0]))  # walker right (cell 1), runner left (stays at 0)
    assert first.live.tolist() == [True, True] and first.rewards.tolist() == pytest.approx([-0.1, -0.1])
    second = game.step(np.array([2, 0]))  # walker reaches the end: +1, terminated, gone
    assert second.terminated.tolist() == [True, False] and second.live.tolist() == [False, True]
    assert second.rewards.tolist() == pytest.approx([1.0, -0.1])
    game.step(np.array([0, 0]))
    last = game.step(np.array([0, 0]))  # step 4: the runner is truncated
    assert last.truncated.tolist() == [False, True] and last.rewards[0] == 0.0 and game.done


def test_a_mid_episode_state_replays_to_the_same_episode():
    game, rng = corridor(), np.random.default_rng(3)
    game.reset(rng)
    for action in ([2, 1], [2, 1], [0, 1]):
        game.step(np.array(action))
    state, copy = game.state_dict(), corridor()
    assert np.array_equal(copy.load_state_dict(state, rng), game.state_dict()["obs"])
    for action in ([2, 1], [1, 0], [2, 1]):
        a, b = game.step(np.array(action)), copy.step(np.array(action))
        assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_an_env_that_ignores_its_seed_is_refused_on_resume():
    game = PettingZooGame("corridor_env:unseeded", {})
    game.reset(np.random.default_rng(0))
    game.step(np.array([1, 1]))
    state = game.state_dict()
    with pytest.raises(ValueError, match="not deterministic given its reset seed"):
        for _ in range(20):  # one of twenty replays differs (the noise draw alone is a float)
            PettingZooGame("corridor_env:unseeded", {}).load_state_dict(state, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("factory", "words"),
    [
        ("corridor_env:dict_observations", ("agent runner", "Dict(", "Box, Discrete or MultiDiscrete")),
        ("corridor_env:image_observations", ("agent runner", "(84, 84, 3)", "21168 floats")),
        ("corridor_env:continuous_actions", ("agent runner", "Box(-1.0, 1.0", "Discrete actions")),
        ("corridor_env:not_an_env", ("returned a str", "not a PettingZoo ParallelEnv")),
        ("corridor_env:nothing", ("corridor_env has no callable nothing",)),
        ("no_such_package.envs:make", ("cannot import no_such_package.envs",)),
        ("corridor_env", ("expected PACKAGE.MODULE:CALLABLE",)),
    ],
)
def test_unsupported_envs_are_refused_in_one_line(factory, words):
    with pytest.raises(UnsupportedEnv) as refusal:
        PettingZooGame(factory, {})
    message = str(refusal.value)
    assert "\n" not in message and message.startswith(f"env.factory={factory}")
    for word in words:
        assert word in message


def test_a_factory_refusing_its_kwargs_is_one_line():
    with pytest.raises(UnsupportedEnv, match=r"refused env.kwargs=\{'lenght': 4\}: TypeError"):
        PettingZooGame(CORRIDOR, {"lenght": 4})


def test_warm_starts_across_games_are_refused():
    lbf, spread = (
        PettingZooGame("dqn_transfer.envs.lbf:parallel_env", {}),
        PettingZooGame("mpe2.simple_spread_v3:parallel_env", {}),
    )
    check_same_game({"env": {"factory": "dqn_transfer.envs.lbf:parallel_env", "kwargs": {"food": 1}}}, lbf)
    with pytest.raises(TransferError, match="trained on the treasure hunt and this run plays mpe2"):
        check_same_game({"env": {"size": 6, "layout": "0.T\n...\n1.T"}}, spread)
    with pytest.raises(TransferError, match="trained on dqn_transfer.envs.lbf:parallel_env and this run plays mpe2"):
        check_same_game({"env": {"factory": "dqn_transfer.envs.lbf:parallel_env"}}, spread)


def test_lbf_declares_its_segments_in_its_observation_order():
    game = PettingZooGame("dqn_transfer.envs.lbf:parallel_env", {"size": 6, "players": 3, "food": 2})
    assert game.obs_layout() == lbf_segments(2, 3)
    assert [name for name, _ in game.obs_layout()] == ["food_0", "food_1", "self", "player_1", "player_2"]
    obs = game.reset(np.random.default_rng(0))
    env = game.env.game  # lbforaging's ForagingEnv (its faster subclass)
    for agent, player in enumerate(env.players):
        self_entry = obs[agent, segment_slices(game.obs_layout())["self"]]
        assert self_entry.tolist() == [*player.position, player.level]


def test_lbf_time_limit_is_a_truncation():
    game = PettingZooGame("dqn_transfer.envs.lbf:parallel_env", {"size": 8, "food": 1, "max_steps": 3})
    game.reset(np.random.default_rng(0))
    outcomes = [game.step(np.zeros(2, dtype=np.int64)) for _ in range(3)]  # NONE: nobody loads
    assert outcomes[-1].truncated.all() and not outcomes[-1].terminated.any() and game.done


# ------------------------------------------------------------------------------------ from the command line


def q_values(tensors: dict[str, np.ndarray], obs: np.ndarray) -> np.ndarray:
    """The Q-values of a DQN agent file's online network (ReLU MLP) on ``obs`` [N, D]."""
    layers = sorted(int(name.split(".")[2]) for name in tensors if name.startswith("q.layers.") and "weight" in name)
    x = obs.astype(np.float64)
    for n, layer in enumerate(layers):
        x = x @ tensors[f"q.layers.{layer}.weight"].T.astype(np.float64) + tensors[f"q.layers.{layer}.bias"]
        if n < len(layers) - 1:
            x = np.maximum(x, 0.0)
    return x


@pytest.mark.slow
def test_lbf_size_to_size_transfer_computes_the_sources_q_values(tmp_path):
    """A source trained with 1 food and 2 players warm-starts 3 food and 3 players: on every state the
    source could see (its entries as the source saw them, whatever the new entries hold) the target's
    Q-values are the source's."""
    small = ("env.kwargs.size=5", "env.kwargs.food=1", "env.kwargs.players=2")
    large = ("env.kwargs.size=7", "env.kwargs.food=3", "env.kwargs.players=3")
    common = ("env=lbf", "agent=double_dqn", "eval_every=100", "eval_episodes=1", "agent.learning_starts=50")
    source = run_train(tmp_path, *common, *small, "total_steps=300", run_dir=tmp_path / "source")
    source_file = source.run_dir / "checkpoints" / "agent_0.safetensors"
    target = run_train(
        tmp_path, *common, *large, "total_steps=0", "transfer=on", f"transfer.source={source_file}",
        run_dir=tmp_path / "target",
    )  # fmt: skip
    source_tensors, source_meta = load_agent_checkpoint(source_file)
    assert source_meta["env"]["factory"] == "dqn_transfer.envs.lbf:parallel_env"
    assert source_meta["env"]["kwargs"]["food"] == 1 and len(source_meta["env"]["observation_spaces"]) == 2
    # States the source saw: observations of its own task; the target's new entries drawn at random.
    game = PettingZooGame("dqn_transfer.envs.lbf:parallel_env", {"size": 5, "food": 1, "players": 2})
    rng = np.random.default_rng(0)
    seen = [game.reset(rng)]
    while len(seen) < 60:
        outcome = game.step(rng.integers(6, size=2))
        seen.append(outcome.obs)
        if game.done:
            seen.append(game.reset(rng))
    source_obs = np.concatenate(seen)
    source_slices, target_layout = segment_slices(lbf_segments(1, 2)), lbf_segments(3, 3)
    target_obs = rng.integers(-1, 7, size=(len(source_obs), sum(w for _, w in target_layout))).astype(np.float32)
    for name, columns in segment_slices(target_layout).items():
        if name in source_slices:
            target_obs[:, columns] = source_obs[:, source_slices[name]]
    expected = q_values(source_tensors, source_obs)
    for i in range(3):
        tensors, meta = load_agent_checkpoint(target.run_dir / "checkpoints" / f"agent_{i}.safetensors")
        assert meta["obs_layout"] == [list(pair) for pair in target_layout]
        np.testing.assert_allclose(q_values(tensors, target_obs), expected, atol=1e-5)
    assert not np.allclose(expected, expected[0])  # the states differ in value: the check has teeth


@pytest.mark.slow
def test_an_env_named_only_on_the_command_line_trains_checkpoints_and_resumes_bit_identically(tmp_path, monkeypatch):
    """``env=pettingzoo env.factory=corridor_env:parallel_env``: a run stopped mid-episode and resumed
    equals the uninterrupted run, evaluation for evaluation and weight for weight."""
    with_corridor(monkeypatch)
    run = (
        "env=pettingzoo",
        f"env.factory={CORRIDOR}",
        "env.kwargs.length=6",
        "env.kwargs.max_steps=15",
        "agent=dqn",
        "agent.exploration_fraction=0",  # epsilon's horizon is fixed when a run starts: the same in both
        "agent.learning_starts=40",
        "agent.hidden=[16]",
        "eval_every=50",
        "eval_episodes=3",
        "checkpoint_every=70",
    )
    whole = run_train(tmp_path, *run, "total_steps=400", run_dir=tmp_path / "whole")
    # Stopped at a step that evaluates anyway (a run ending elsewhere adds a final evaluation there, a
    # record the uninterrupted run has not), in the middle of an episode: its checkpoint holds the
    # episode's seed and actions.
    stopped = run_train(tmp_path, *run, "total_steps=250", run_dir=tmp_path / "stopped")
    _, state = load_training_state(stopped.run_dir / "checkpoints" / "training_state.safetensors")
    assert state["episode"] is not None and len(state["episode"]["game"]["actions"]) > 0
    resumed = run_train(tmp_path, *run, "total_steps=400", "resume=true", run_dir=tmp_path / "stopped")
    assert "resumed" in resumed.output
    assert without_timing(read_metrics(resumed.run_dir)) == without_timing(read_metrics(whole.run_dir))
    for i in range(2):
        a, b = (agent_meta(r.run_dir / "checkpoints" / f"agent_{i}.safetensors") for r in (resumed, whole))
        assert a["digest"] == b["digest"] and a["episodes"] == b["episodes"]
    assert agent_meta(whole.run_dir / "checkpoints" / "agent_0.safetensors")["env"]["observation_spaces"] == [
        "Discrete(6)",
        "Box(0.0, 1.0, (2,), float32)",
    ]


# Learners whose evaluations differ with their episodes' seeds: SARSA meets LBF states it has not visited
# (every action tied), and every MPE start is another continuous position.
QUICK_LEARNERS = pytest.mark.parametrize(
    "learning",
    [("env=lbf", "agent=sarsa"), ("env=mpe_spread", "agent.hidden=[8]", "agent.learning_starts=20")],
    ids=["lbf", "mpe_spread"],
)


@QUICK_LEARNERS
def test_an_evaluation_of_another_game_depends_on_neither_eval_every_nor_the_replicas_beside_it(tmp_path, learning):
    """The evaluation at step N resets its episodes from (seed, N, episode) alone (issue #31): a run of 2
    replicas evaluated every 50 steps records at steps 0, 100, 200 what the lone run of each seed,
    evaluated every 100 steps, records there. Before, episodes were keyed by the evaluation's index, so
    step 100 was the third evaluation of one and the second of the other."""
    common = (*learning, "total_steps=200", "eval_episodes=3", "progress=false")
    train(plan_run(compose_config(*common, "eval_every=50", "replicas.seeds=2")), tmp_path / "replicas")
    for seed in (0, 1):
        train(plan_run(compose_config(*common, "eval_every=100", f"seed={seed}")), tmp_path / f"lone_{seed}")
        lone = without_timing(read_metrics(tmp_path / f"lone_{seed}"))
        replica = without_timing(read_metrics(tmp_path / "replicas" / f"seed_{seed}"))
        assert [record["step"] for record in lone] == [0, 100, 200]
        assert [record for record in replica if record["step"] % 100 == 0] == lone
        assert len({record["team_return"] for record in replica}) > 1  # the episodes' numbers vary: not vacuous


@QUICK_LEARNERS
def test_a_finished_run_extended_evaluates_as_the_longer_run(tmp_path, learning):
    """A run of 150 steps ends with an evaluation off its eval_every grid (step 150); resumed to 200
    steps, it records at every step of the uninterrupted 200-step run that run's evaluation (issue #31:
    the extra evaluation shifted every later one's episodes)."""
    # Epsilon's horizon is fixed when a run starts: without exploration both runs train alike.
    common = (*learning, "agent.exploration_fraction=0", "eval_every=100", "eval_episodes=3", "progress=false")
    train(plan_run(compose_config(*common, "total_steps=200")), tmp_path / "whole")
    train(plan_run(compose_config(*common, "total_steps=150")), tmp_path / "extended")
    train(plan_run(compose_config(*common, "total_steps=200", "resume=true")), tmp_path / "extended")
    whole, extended = (without_timing(read_metrics(tmp_path / name)) for name in ("whole", "extended"))
    assert [record["step"] for record in extended] == [0, 100, 150, 200]
    assert [record for record in extended if record["step"] != 150] == whole


@pytest.mark.slow
@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        (("env=pettingzoo", "env.factory=corridor_env:dict_observations"), ("error:", "Dict(")),
        (("env=pettingzoo", "env.factory=no_such_package:make"), ("error:", "cannot import no_such_package")),
        (("env=lbf", "transfer=on"), ("error:", "transfer.source_task=single")),
        (("env=pettingzoo", "env.factory=corridor_env:turn_based"), ("error:", "is_parallelizable", "ParallelEnv")),
    ],
)
def test_bad_games_are_refused_in_one_line(tmp_path, monkeypatch, overrides, words):
    """... and leave nothing behind: no run directory (issue #31: an AEC factory left one)."""
    with_corridor(monkeypatch)
    result = run_train(tmp_path, *overrides, check=False)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.returncode == 1 and len(lines) == 1, result.output
    for word in words:
        assert word in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_a_parallelizable_aec_env_is_played_as_its_parallel_env():
    """mpe2's ``env`` (AEC, declared parallelizable) plays step for step as its ``parallel_env``."""
    aec, parallel = (PettingZooGame(f"mpe2.simple_adversary_v3:{name}", {}) for name in ("env", "parallel_env"))
    assert (aec.num_agents, aec.obs_dim, aec.num_actions) == (
        parallel.num_agents,
        parallel.obs_dim,
        parallel.num_actions,
    )
    assert np.array_equal(aec.reset(np.random.default_rng(3)), parallel.reset(np.random.default_rng(3)))
    actions = np.random.default_rng(4)
    while not parallel.done:
        joint = actions.integers(parallel.num_actions, size=parallel.num_agents)
        a, b = aec.step(joint), parallel.step(joint)
        assert np.array_equal(a.obs, b.obs) and np.array_equal(a.rewards, b.rewards)
    assert aec.done and parallel.steps == 25  # max_cycles


@pytest.mark.parametrize(
    ("overrides", "ignored"),
    [
        (("env=lbf",), []),
        (("env=simple", "env.factory=corridor_env:parallel_env"), []),  # env=simple's own map keys are not the user's
        (("env=lbf", "mode=competitive", "env.size=6"), []),  # the defaults, set again
        (
            ("env=lbf", "env.size=10", "mode=cooperative", "env.map_seed=3"),
            ["size", "mode"],
        ),  # map_seed: its reset seed
        (("env=simple", "env.factory=corridor_env:parallel_env", "env.num_traps=5"), ["num_traps"]),
    ],
)
def test_treasure_hunt_keys_on_another_game_are_the_ones_the_user_set(overrides, ignored):
    assert treasure_hunt_settings(compose_config(*overrides).env) == ignored


def random_team_return(factory: str, kwargs: dict, episodes: int, seed: int) -> float:
    """The mean team return of a uniformly random policy (every live agent picks any action)."""
    game, rng = PettingZooGame(factory, kwargs), np.random.default_rng(seed)
    total = 0.0
    for _ in range(episodes):
        game.reset(rng)
        while not game.done:
            live = game.live
            total += float(game.step(rng.integers(game.num_actions, size=game.num_agents)).rewards[live].sum())
    return total / episodes


# How far above a random policy trained teams are held (measured: see each test's docstring).
LBF_MEAN_GAIN, LBF_SEED_GAIN = 0.3, 0.2
MPE_MEAN_GAIN, MPE_SEED_GAIN = 8.0, 4.0


def greedy_and_random(run_dir: Path, episodes: int, random_episodes: int) -> tuple[list[float], float]:
    """A finished run's teams (one per replica, i.e. per seed), each played greedily for ``episodes``, and a
    uniformly random policy on their task: the teams' mean team returns, and the random policy's."""
    trained = []
    for replica in RunDir(run_dir).replica_dirs():
        team = load_team(replica)
        assert isinstance(team.game, PettingZooGame)
        trained.append(evaluate(team.learner, team.game, episodes=episodes, seed=0, step=0)["team_return"])
    return trained, random_team_return(team.game.factory, team.game.kwargs, random_episodes, seed=1)


@pytest.mark.slow
def test_the_plain_lbf_command_learns_well_above_a_random_policy(tmp_path):
    """``python train.py env=lbf agent=double_dqn`` with its shipped defaults (8x8, 2 players, 1 food any
    player loads, 25 steps; gamma 0.95, 20,000 steps), seeds 0..2: each trained team's greedy return over 200
    episodes against a uniformly random policy's on the same task (the team return is the food collected,
    <= 1). Judged over the seeds: their mean well above random, and at least 2 of the 3 above it."""
    result = run_train(tmp_path, "env=lbf", "agent=double_dqn", "replicas.seeds=3")
    config = load_config(result.run_dir)
    assert config is not None and config["total_steps"] == 20_000 and config["agent"]["gamma"] == 0.95
    trained, random = greedy_and_random(result.run_dir, episodes=200, random_episodes=1000)
    assert 0.2 < random < 0.4, random  # about 0.30
    assert np.mean(trained) > random + LBF_MEAN_GAIN, (trained, random)
    assert sum(t > random + LBF_SEED_GAIN for t in trained) >= 2, (trained, random)


@pytest.mark.slow
def test_mpe_spread_learns_above_a_random_policy(tmp_path):
    """``python train.py env=mpe_spread agent=double_dqn`` for 10,000 of its 30,000 steps (gamma 0.9), seeds
    0..2: each team's greedy return over 100 episodes against a uniformly random policy's, about -79
    (episodes vary by about 23, so 500 random episodes pin it to about 1). Judged over the seeds: their mean
    above random, and at least 2 of the 3 above it."""
    result = run_train(tmp_path, "env=mpe_spread", "agent=double_dqn", "total_steps=10000", "replicas.seeds=3")
    trained, random = greedy_and_random(result.run_dir, episodes=100, random_episodes=500)
    assert -85 < random < -73, random
    assert np.mean(trained) > random + MPE_MEAN_GAIN, (trained, random)
    assert sum(t > random + MPE_SEED_GAIN for t in trained) >= 2, (trained, random)


# ------------------------------------------------------------------------------------ watching, per-replica sources


def trained_run(run_dir: Path, factory: str, kwargs: dict, seeds: int = 1, **keys) -> Path:
    """A short Double DQN run of another game in this process (a few updates: its checkpoints are real)."""
    config = TrainConfig(
        env=EnvConfig(factory=factory, kwargs=kwargs),
        agent=AgentConfig(hidden=[8], learning_starts=10),
        replicas=ReplicasConfig(seeds=seeds),
        total_steps=20,
        eval_every=20,
        eval_episodes=1,
        progress=False,
        **keys,
    )
    train(plan_run(config), run_dir)
    return run_dir


@pytest.fixture(scope="module")
def spread_run(tmp_path_factory) -> Path:
    kwargs = {"N": 2, "max_cycles": 5, "continuous_actions": False}
    return trained_run(tmp_path_factory.mktemp("spread") / "run", SPREAD, kwargs)


def test_play_writes_a_gif_of_another_games_greedy_episodes(spread_run, tmp_path, capsys, monkeypatch):
    """The particle world draws with pygame, headless here: each frame is the env's own picture."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    gif = tmp_path / "spread.gif"
    assert play([str(spread_run), "--episodes", "2", "--gif", str(gif)]) == 0
    out = capsys.readouterr().out
    assert f"double_dqn team of 2 on {SPREAD}, trained 20 steps" in out
    assert "episode 1: 5 steps, team return -" in out and "episode 2: 5 steps" in out
    assert f"wrote {gif} (12 frames)" in out  # 5 steps plus the first, twice
    with Image.open(gif) as picture:
        assert picture.n_frames == 12 and max(picture.size) <= 522  # scaled to 480 a side, plus the caption
        frames = []
        for index in (0, 5):
            picture.seek(index)
            frames.append(np.asarray(picture.convert("RGB")))
    assert not np.array_equal(frames[0], frames[1])  # the agents moved


def test_play_refuses_another_game_it_cannot_draw_in_one_line(spread_run, tmp_path, capsys, monkeypatch):
    """LBF draws with pyglet, which needs a display; the corridor has no rgb_array mode; --ansi is the
    treasure hunt's grid. Each is one ``error:`` line and no GIF; an export (map, model card) is refused."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setenv("PYTHONPATH", str(TESTS))
    monkeypatch.syspath_prepend(str(TESTS))
    lbf = trained_run(tmp_path / "lbf", LBF, {"size": 5, "food": 1})
    corridor_run = trained_run(tmp_path / "corridor", CORRIDOR, {"length": 4})
    gif = tmp_path / "out.gif"
    cases = [
        ([str(lbf), "--gif", str(gif)], f"env.factory={LBF}: the env cannot draw an RGB frame here (NoSuchDisplay"),
        ([str(corridor_run), "--gif", str(gif)], "render_modes are [], without rgb_array"),
        ([str(spread_run), "--ansi"], "--ansi prints the treasure hunt's grid"),
    ]
    for argv, words in cases:
        assert play(argv) == 1
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.count("\n") == 1 and captured.err.startswith("error: ")
        assert words in captured.err, captured.err
        assert not gif.exists()
    assert play([str(lbf)]) == 0  # without a GIF nothing is drawn: it plays
    assert "episode 1: " in capsys.readouterr().out
    with pytest.raises(ExportError, match=f"a team of {SPREAD}: an export .* is a treasure hunt's"):
        export_team(spread_run, tmp_path / "export")


def test_a_run_of_replicas_as_the_source_transfers_seed_for_seed(tmp_path):
    """``transfer.source`` = a run of replicas: each replica of a run of replicas starts from the source
    replica of its seed; a seed the source lacks is refused in one line; a lone run still must name one."""
    source = trained_run(tmp_path / "source", LBF, {"size": 5, "food": 1}, seeds=3)

    def sources(seed: int, seeds: int) -> list[list[Path]] | None:
        transfer = TransferConfig(enabled=True, source=str(source))
        config = TrainConfig(
            env=EnvConfig(factory=LBF, kwargs={"size": 5, "food": 2}),
            transfer=transfer,
            replicas=ReplicasConfig(seeds=seeds),
            seed=seed,
        )
        return transfer_sources(plan_run(config), tmp_path)

    checkpoints = [source / f"seed_{s}" / "checkpoints" for s in (1, 2)]  # a team of this run's size: i from i
    assert sources(1, 2) == [[run / "agent_0.safetensors", run / "agent_1.safetensors"] for run in checkpoints]
    with pytest.raises(CheckpointError, match="has no seed_3: each replica of this run starts from the source"):
        sources(2, 2)
    with pytest.raises(CheckpointError, match="is a run of 3 replicas: pass one replica's directory"):
        sources(0, 1)


@pytest.mark.parametrize(
    "learning",
    [
        ("agent=dqn", "agent.share_parameters=true", "agent.learning_starts=40", "agent.hidden=[16]"),
        ("agent=sarsa", "transfer.exchange=best", "transfer.exchange_every=5", "replicas.seeds=2"),
        ("agent=qlearning", "transfer.exchange=shared_replay", "transfer.exchange_every=5"),
    ],
    ids=["shared_parameters", "exchange_best_replicas", "exchange_shared_replay"],
)
def test_parameter_sharing_and_knowledge_exchange_train_on_another_game(tmp_path, monkeypatch, learning):
    """The team-level options are not the treasure hunt's: they run on a game named on the command line
    and evaluate into every replica's metrics.jsonl (``best`` logs the agent it copied, every 5 episodes)."""
    with_corridor(monkeypatch)
    overrides = ("env=pettingzoo", f"env.factory={CORRIDOR}", *learning, "total_steps=300", "eval_every=100")
    result = run_train(tmp_path, *overrides, "logger=[csv]")
    replicas = "replicas.seeds=2" in learning
    runs = [result.run_dir / "seed_0", result.run_dir / "seed_1"] if replicas else [result.run_dir]
    for run in runs:
        assert [line["step"] for line in read_metrics(run)] == [0, 100, 200, 300]
        copies = (run / "scalars.csv").read_text().count("team/exchange_best_agent")
        assert (copies >= 3) if "transfer.exchange=best" in learning else copies == 0
