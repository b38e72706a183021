"""``shared_replay`` leaves out a team-mate's obstacle bounces: a move into an obstacle sends the mover
back to its own start, a cell no team-mate starts on (a map has one start per agent, so the case of two
agents sharing a start cannot be built). Worked by hand on a 3x3 map, and the game's bounce flags checked
against the map through the training loop, for one game and for a batch of four.

Actions: 0 up, 1 down, 2 left, 3 right; cell index = row * n + col.
"""

import dataclasses

import numpy as np
import pytest
from test_train_cli import MAP

from dqn_transfer.agents import Transition, make_learner
from dqn_transfer.config import AgentConfig, ReplicasConfig, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Engine, Exchange
from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts
from dqn_transfer.envs.maps import parse_layout
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.exchange.shared_replay import exchange_replay
from dqn_transfer.storage.checkpoint import encode_training_state, load_training_state
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3
# Agent 0 starts on (0,0), agent 1 on (1,0), the obstacle is (1,1).
SMALL_MAP = "0.T\n1#.\n...\n"
TABULAR = AgentConfig(algorithm=Algorithm.qlearning, lr=0.5, gamma=0.9)
DQN = AgentConfig(algorithm=Algorithm.dqn, engine=Engine.numpy, hidden=[8], learning_starts=10**6)


def window() -> tuple[TreasureHuntGame, list[np.ndarray], list[Transition], list[np.ndarray]]:
    """Two joint steps on SMALL_MAP: agent 0 right (0,0) -> (0,1), then left back; agent 1 right into the
    obstacle, so back to its start (1,0), then down to (2,0). Returns the game, the observations before
    each step and after the last, the transitions and the game's bounce flags."""
    game = TreasureHuntGame(parse_layout(SMALL_MAP))
    obs = [game.reset(np.random.default_rng(0))]
    transitions, bounced = [], []
    for actions in ([RIGHT, RIGHT], [LEFT, DOWN]):
        live = game.live
        out = game.step(np.array(actions))
        transitions.append(
            Transition(obs[-1], np.array(actions), out.rewards, out.obs, out.terminated, out.truncated, live)
        )
        bounced.append(out.bounced)
        obs.append(out.obs)
    return game, obs, transitions, bounced


def test_the_game_reports_the_bounce_of_the_agent_that_moved_into_the_obstacle():
    game, obs, _, bounced = window()
    assert [b.tolist() for b in bounced] == [[False, True], [False, False]]
    assert [o[:, :9].argmax(axis=1).tolist() for o in obs] == [[0, 3], [1, 3], [0, 6]]  # cells, by position one-hot
    assert game.positions.tolist() == [[0, 0], [2, 0]]


@pytest.mark.parametrize("hp", [TABULAR, DQN], ids=["tabular", "dqn"])
def test_a_team_mates_bounce_is_not_shared_and_its_ordinary_moves_are(hp):
    game, obs, transitions, bounced = window()
    team = make_learner(hp, 2, game.obs_layout(), game.num_actions, seed=0)
    exchange_replay(team, transitions, bounced)
    at_start_1, at_start_0, at_01 = obs[0][1], obs[0][0], obs[1][0]  # agent 1 at (1,0); agent 0 at (0,0), (0,1)
    if hp is DQN:
        replay = team.replay
        actions = replay.storage[:, :, replay.columns["actions"]]
        assert replay.size.tolist() == [1, 2]  # agent 0: agent 1's move down only; agent 1: both of agent 0's
        assert actions[0, :1].tolist() == [DOWN] and actions[1, :2].tolist() == [RIGHT, LEFT]
        np.testing.assert_array_equal(replay.storage[0, 0, replay.columns["obs"]], at_start_1)
        return
    # Agent 0 on agent 1's move down: Q(s, down) = 0 + 0.5 * (-1 + 0.9 * 0 - 0); the bounce right is not
    # learned (had it been, Q(s, right) would be 0.5 * (-1 + 0.9 * 0) = -0.5 too).
    np.testing.assert_array_equal(team.q_values(np.stack([at_start_1, at_start_1]))[0], [0.0, -0.5, 0.0, 0.0])
    # Agent 1 on agent 0's two moves: Q((0,0), right) = -0.5; Q((0,1), left) = 0.5 * (-1 + 0.9 * max(0, 0, 0, -0.5)).
    np.testing.assert_array_equal(team.q_values(np.stack([at_start_0, at_start_0]))[1], [0.0, 0.0, 0.0, -0.5])
    np.testing.assert_array_equal(team.q_values(np.stack([at_01, at_01]))[1], [0.0, 0.0, -0.5, 0.0])
    np.testing.assert_array_equal(team.q_values(np.stack([at_start_0, at_start_0]))[0], [0.0] * 4)  # not its own


def map_bounces(transitions: list[Transition]) -> np.ndarray:
    """``[T, K]``: who moved into one of MAP's obstacles, read off the observations' position one-hot and
    the actions, by the map's text alone."""
    rows = MAP.split()
    n = len(rows)
    moves = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}
    found = np.zeros((len(transitions), len(transitions[0].live)), dtype=bool)
    for t, step in enumerate(transitions):
        for k in np.flatnonzero(step.live):
            r, c = divmod(int(step.obs[k, : n * n].argmax()), n)
            dr, dc = moves[int(step.actions[k])]
            found[t, k] = 0 <= r + dr < n and 0 <= c + dc < n and rows[r + dr][c + dc] == "#"
    return found


def shared_replay_run(seeds: int = 1) -> TrainConfig:
    return TrainConfig(
        env=EnvConfig(layout=MAP),
        agent=TABULAR,
        total_steps=200,
        eval_every=200,
        eval_episodes=1,
        progress=False,
        replicas=ReplicasConfig(seeds=seeds),
        transfer=TransferConfig(exchange=Exchange.shared_replay, exchange_every=2),
    )


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
@pytest.mark.parametrize("seeds", [1, 4])
def test_the_loop_hands_the_exchange_the_games_bounces(tmp_path, monkeypatch, seeds):
    import dqn_transfer.exchange.shared_replay as shared_replay_module

    windows = []

    def spy(team, transitions, bounced):
        windows.append((list(transitions), np.stack(bounced)))

    monkeypatch.setattr(shared_replay_module, "exchange_replay", spy)
    trainer = Trainer(plan_run(shared_replay_run(seeds)), tmp_path / "run")
    trainer.run()
    assert isinstance(trainer.games, TreasureHunts)
    assert len(windows) >= 2 * seeds
    for transitions, bounced in windows:
        np.testing.assert_array_equal(bounced, map_bounces(transitions))
    assert sum(int(bounced.sum()) for _, bounced in windows) > 0  # the runs did bounce


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_a_checkpoint_without_the_windows_bounces_resumes_it_as_it_was_shared_before(tmp_path):
    """A checkpoint written before bounces were recorded: its pending window counts as bounce-free."""
    trainer = Trainer(plan_run(shared_replay_run()), tmp_path)
    trainer.run()
    pending = len(trainer.exchange.transitions[0])
    assert pending > 0  # the run ended inside a window
    path = RunDir(tmp_path).training_state
    arrays, meta = load_training_state(path)
    assert arrays.pop("exchange/bounced").shape == (pending, 2)
    path.write_bytes(encode_training_state(arrays, meta))
    resumed = Trainer(plan_run(dataclasses.replace(shared_replay_run(), resume=True)), tmp_path)
    resumed.prepare()
    assert [b.tolist() for b in resumed.exchange.bounced[0]] == [[False, False]] * pending
