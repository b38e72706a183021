"""The training loop's joint steps of a DQN team on the treasure hunt, compiled around the networks:
everything but a forward pass and a gradient step runs in one kernel, step after step.

These are the steps of :meth:`~dqn_transfer.training.trainer.Trainer.run` with the calls it makes
inlined: :meth:`BatchedDQN.act <dqn_transfer.agents.dqn_base.BatchedDQN.act>` (each replica's
exploration draws from its generator, ``epsilon_greedy``'s two per agent, all uniforms first),
:class:`~dqn_transfer.envs.game.TreasureHunts`' step (the rules' kernel), the replay's ``add`` (the
live agents' transitions written into their rows), the update window, the episode sums and an ended
episode's restart (:func:`~dqn_transfer.training.loop_kernels.add_episode_step`). The kernel returns
to Python only for what the networks do: when an agent exploits, for the greedy actions of the step
(:meth:`BatchedDQN.greedy_actions <dqn_transfer.agents.dqn_base.BatchedDQN.greedy_actions>`, one
batched forward), and when a round of gradient steps or a target sync is due
(:meth:`BatchedDQN.learn <dqn_transfer.agents.dqn_base.BatchedDQN.learn>`), then carries on. The same
order and the same floats as the Python steps, so a run is the same bit for bit either way
(``tests/test_compiled_steps.py``, the reference runs). Runs this does not cover stay in Python
(:func:`~dqn_transfer.training.trainer.compiled_steps` says which): VDN's joint replay, exchanges inside
the loop, games without the treasure hunt's rules.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.compiled import kernel
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import rules, tie_draws
from dqn_transfer.envs.game import TreasureHunts
from dqn_transfer.training.loop_kernels import EndedEpisodes, UpdateWindow, add_episode_step, epsilon_at

# Where a call of the kernel starts a step, and why it returns.
ACT, FINISH = 0, 1  # start: draw the exploration (ACT), or play the drawn and greedy actions (FINISH)
GREEDY, LEARN, BOUNDARY = 0, 1, 2  # returned: greedy actions wanted, learning due, ``last`` or a full record


class DQNSteps:
    """The compiled steps of one run (:func:`~dqn_transfer.training.trainer.compiled_steps`), over the
    arrays the learner, its replay, the games, the episode sums and the update window own (changed in place)."""

    def __init__(self, learner: BatchedDQN, games: TreasureHunts, schedule: Any, sums: Any, window: UpdateWindow):
        self.learner, self.games, self.schedule, self.sums, self.window = learner, games, schedule, sums, window
        rows = learner.num_rows
        self.actions = np.zeros((games.num_replicas, games.num_agents), dtype=np.int64)  # -1: greedy wanted
        self.greedy = np.zeros(rows, dtype=np.int64)
        self.live = np.zeros(rows, dtype=np.bool_)  # who acted in the step in progress
        self.uniforms = np.zeros(games.num_agents)
        self.explore_words = np.zeros((games.num_replicas, tie_draws.WORDS), dtype=np.uint64)
        self.learning = np.array([learner.learning_starts, learner.train_freq, learner.target_update], dtype=np.int64)
        self.team = games.reward_mode is RewardMode.team
        self.ended = EndedEpisodes(games.num_replicas, games.num_agents, sums.team_metrics)

    def run(self, step: int, last: int) -> list[tuple[int, int, np.ndarray]]:
        """Joint steps from ``step`` to ``last``; returns each episode that ended on the way, in order, as
        ``(step, replica, values)`` (:meth:`EpisodeSums.ended_values`' row). Its game was restarted."""
        learner, games, replay, window = self.learner, self.games, self.learner.replay, self.window
        for words, rng in zip(self.explore_words, learner.rngs):
            tie_draws.pack(rng, words)
        game = games.kernel_arrays()
        obs = games.obs.reshape(learner.num_rows, -1)
        episodes: list[tuple[int, int, np.ndarray]] = []
        start = ACT
        while True:
            reason, step = _run(
                start,
                step,
                last,
                self.actions,
                self.greedy,
                self.live,
                self.uniforms,
                self.explore_words,
                learner.num_actions,
                self.schedule.start,
                self.schedule.end,
                self.schedule.duration,
                replay.storage,
                replay.ptr,
                replay.size,
                self.learning,
                self.sums.returns,
                self.sums.lengths,
                self.sums.traps,
                self.sums.team_return,
                window.sums,
                window.steps,
                self.ended.rows,
                self.ended.count,
                self.team,
                *games.rule_constants,
                game,
            )
            if self.ended.count[0]:
                episodes += self.ended.take()
            if reason == GREEDY:
                self.greedy[:] = learner.greedy_actions(obs)
                start = FINISH
            elif reason == LEARN:
                window.add(*learner.learn(step))
                start = ACT
            elif step < last:  # the record of ended episodes was full
                start = ACT
            else:
                break
        games.keep_draws()
        for words, rng in zip(self.explore_words, learner.rngs):
            tie_draws.unpack(words, rng)
        return episodes


@kernel
def _run(
    start,
    step,
    last,
    actions,
    greedy,
    live,
    uniforms,
    explore_words,
    num_actions,
    eps_start,
    eps_end,
    eps_duration,
    storage,
    ptr,
    size,
    learning,
    returns,
    lengths,
    traps,
    team_return,
    window_sums,
    window_steps,
    ended,
    num_ended,
    team,
    rewards,
    max_steps,
    team_rewards,
    announce,
    game,
):
    """The steps of :meth:`DQNSteps.run` (see the module docstring) from ``step``, entered at ``start``;
    returns why it stopped (GREEDY, LEARN, BOUNDARY) and the step reached."""
    tables, state, out = game[: rules.TABLES_END], game[rules.TABLES_END : rules.STATE_END], game[rules.STATE_END :]
    tables, state, out = rules.Tables(*tables), rules.State(*state), rules.Outcome(*out)
    replicas, agents = state.pos.shape
    obs = state.obs.reshape(replicas * agents, -1)
    width = obs.shape[1]
    capacity = storage.shape[1]
    learning_starts, train_freq, target_update = learning
    while True:
        if start == ACT:
            if step >= last or num_ended[0] + replicas > ended.shape[0]:
                return BOUNDARY, step
            # 1. act (BatchedDQN.act): per replica, epsilon_greedy's K uniforms, then K random actions;
            # -1 where the agent exploits (its greedy action comes from the networks)
            wanted = False
            for r in range(replicas):
                for a in range(agents):
                    uniforms[a] = tie_draws.uniform(explore_words[r])
                for a in range(agents):
                    row = r * agents + a
                    random_action = tie_draws.integers(explore_words[r], num_actions) if num_actions > 1 else 0
                    epsilon = epsilon_at(step, eps_start[row], eps_end[row], eps_duration[row])
                    actions[r, a] = random_action if uniforms[a] < epsilon else -1
                    live[row] = state.live[r, a]
                    wanted = wanted or (live[row] and actions[r, a] < 0)
            start = FINISH
            if wanted:
                return GREEDY, step
        # 2. the greedy actions in, non-live agents' 0; the live agents' observations and actions stored
        # (ReplayBuffer.add), the games' step, then their rewards, next observations and terminations
        for r in range(replicas):
            for a in range(agents):
                row = r * agents + a
                if not live[row]:
                    actions[r, a] = 0
                    continue
                if actions[r, a] < 0:
                    actions[r, a] = greedy[row]
                slot = storage[row, ptr[row]]
                slot[:width] = obs[row]
                slot[2 * width + 1] = actions[r, a]
        rules.step(tables, state, actions, out, rewards, max_steps, team_rewards, announce)
        step += 1
        for r in range(replicas):
            for a in range(agents):
                row = r * agents + a
                if not live[row]:
                    continue
                slot = storage[row, ptr[row]]
                slot[width : 2 * width] = obs[row]
                slot[2 * width] = out.rewards[r, a]
                slot[2 * width + 2] = out.terminated[r, a]
                ptr[row] = (ptr[row] + 1) % capacity
                size[row] = min(size[row] + 1, capacity)
        # 3. the episodes' sums; an ended episode recorded and its game restarted
        add_episode_step(step, tables, state, out, team, returns, lengths, traps, team_return, ended, num_ended)
        start = ACT
        # 4. learning (BatchedDQN.learn: a round of gradient steps, a target sync) when due; else the
        # update window counts a step without updates
        if (step > learning_starts and step % train_freq == 0) or step % target_update == 0:
            return LEARN, step
        if window_steps[0] == 0:
            window_sums[:] = 0.0
        window_steps[0] += 1
