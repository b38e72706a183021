"""``transfer.exchange=sham``, shared_replay's negative control: each agent learns from as many
transitions as shared_replay would give it, all of them its own (worked out by hand); in training it
changes the run, and a run killed mid-way resumes bit for bit."""

import numpy as np
import pytest
from test_exchange_methods import final_digests, run_config
from test_train_cli import kill_and_resume

from dqn_transfer.agents import Transition
from dqn_transfer.enums import Exchange
from dqn_transfer.exchange.sham import sham_replay
from dqn_transfer.exchange.shared_replay import exchange_replay
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

K = 3
# Who moved at each of the window's three steps, and who of them moved into an obstacle.
LIVE = np.array([[True, True, True], [True, False, True], [True, True, False]])
BOUNCED = np.array([[False, False, False], [False, False, True], [False, False, False]])


class Recorder:
    """A team that records what each agent is given to learn from: the actions, coded step * 10 + agent."""

    num_agents = K

    def __init__(self) -> None:
        self.given: dict[int, list[int]] = {i: [] for i in range(K)}

    def learn_from(self, i, experience) -> None:
        self.given[i] += experience.actions.tolist()


def window() -> list[Transition]:
    obs = np.zeros((K, 2), np.float32)
    return [
        Transition(obs, 10 * t + np.arange(K), np.ones(K, np.float32), obs, np.zeros(K, bool), np.zeros(K, bool), live)
        for t, live in enumerate(LIVE)
    ]


def test_sham_gives_each_agent_its_own_moves_as_many_as_its_team_mates_would_give():
    # Moves (live, not bounced): agent 0 at steps 0, 1, 2; agent 1 at 0, 2; agent 2 at 0 (it bounced at 1,
    # was done at 2). shared_replay hands agent 0 the 2 + 1 = 3 others' moves, agent 1 3 + 1 = 4, agent 2 3 + 2 = 5.
    shared, sham = Recorder(), Recorder()
    exchange_replay(shared, window(), list(BOUNCED))
    sham_replay(sham, window(), list(BOUNCED))
    assert shared.given == {0: [1, 21, 2], 1: [0, 10, 20, 2], 2: [0, 10, 20, 1, 21]}
    assert sham.given == {0: [0, 10, 20], 1: [1, 21, 1, 21], 2: [2, 2, 2, 2, 2]}


def test_an_agent_without_moves_and_an_empty_window_are_given_nothing():
    alone = Recorder()
    sham_replay(alone, window()[:1], [np.array([False, True, True])])  # agents 1 and 2 bounced: only 0 moved
    assert alone.given == {0: [], 1: [], 2: []}  # agent 0's team-mates gave nothing; they have no moves
    sham_replay(alone, [], [])
    assert alone.given == {0: [], 1: [], 2: []}


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_a_sham_run_differs_from_none_and_resumes_bit_for_bit(tmp_path, monkeypatch):
    Trainer(plan_run(run_config(Exchange.none)), tmp_path / "none").run()
    resumed, reference = kill_and_resume(
        tmp_path,
        monkeypatch,
        lambda resume=False: run_config(Exchange.sham, resume),
        dies=lambda trainer: trainer.replicas[0].counters.episodes > 4,
    )
    assert resumed == reference
    assert final_digests(tmp_path / "killed") == final_digests(tmp_path / "reference")
    assert final_digests(tmp_path / "reference") != final_digests(tmp_path / "none")
