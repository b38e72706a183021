"""Section 3, per-step cost as the team grows: one batched learner against K separate learners.

K agents on ``BENCH_MAP`` generated for K starts, driven as the trainer drives them: act, step the
game, ``learner.update(Transition(...), step)``. Batched: one ``DQNLearner`` for the K agents (stacked
weights, one Adam step). Separate: K single-agent ``DQNLearner`` instances, one after another in a
Python loop, each given its own row of the joint transition.
"""

from __future__ import annotations

import numpy as np

from dqn_transfer.agents import DQNLearner, Transition
from dqn_transfer.benchmark.config import BENCH_AGENT, BENCH_MAP
from dqn_transfer.config import AgentConfig
from dqn_transfer.envs import make_game
from dqn_transfer.timing import Stopwatch


class TeamRig:
    """K agents, batched (``separate=False``) or as K separate learners (``separate=True``).

    Construction plays ``learning_starts`` exploring steps (replay filling, no gradient step, untimed),
    so every timed step trains. ``step_count`` counts the joint env steps played so far.
    """

    def __init__(self, num_agents: int, separate: bool, seed: int, agent: AgentConfig = BENCH_AGENT):
        self.num_agents, self.separate, self.agent = num_agents, separate, agent
        self.game = make_game(**BENCH_MAP, num_agents=num_agents)
        layout, actions = self.game.obs_layout(), self.game.num_actions
        if separate:
            self.learners = [DQNLearner(1, layout, actions, agent, seed=seed + i) for i in range(num_agents)]
        else:
            self.learners = [DQNLearner(num_agents, layout, actions, agent, seed=seed)]
        self.rng = np.random.default_rng(seed)
        self.obs = self.game.reset(self.rng)
        self.step_count = 0
        for _ in range(agent.learning_starts):
            self._step(agent.eps_start)

    def _step(self, epsilon: float) -> None:
        game, obs = self.game, self.obs
        live = game.live
        if self.separate:
            actions = np.concatenate(
                [learner.act(obs[i : i + 1], live[i : i + 1], epsilon) for i, learner in enumerate(self.learners)]
            )
        else:
            actions = self.learners[0].act(obs, live, epsilon)
        next_obs, rewards, terminated, truncated, *_ = game.step(actions)
        self.step_count += 1
        transition = Transition(obs, actions, rewards, next_obs, terminated, truncated, live)
        if self.separate:
            for i, learner in enumerate(self.learners):  # agent i's row of the joint transition, every field [1, ...]
                learner.update(Transition(*(field[i : i + 1] for field in transition)), self.step_count)
        else:
            self.learners[0].update(transition, self.step_count)
        self.obs = game.reset(self.rng) if game.done else next_obs

    def run(self, steps: int) -> Stopwatch:
        """Time ``steps`` joint env steps, each with its gradient update (epsilon = eps_end)."""
        with Stopwatch() as watch:
            for _ in range(steps):
                self._step(self.agent.eps_end)
        return watch
