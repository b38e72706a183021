"""The training loop's joint steps of a tabular team on the treasure hunt, compiled: act, step the games,
learn, add up the episodes and restart the ended ones, step after step in one kernel call, up to the
next boundary (an evaluation, a training-curve point, a checkpoint, the end).

These are the steps of :meth:`~dqn_transfer.training.trainer.Trainer.run` with every call it makes
inlined: :meth:`TabularLearner.act <dqn_transfer.agents.tabular.TabularLearner.act>` (state ids from the
observation code, the counter-based draws, epsilon-greedy, SARSA's cached next action),
:class:`~dqn_transfer.envs.game.TreasureHunts`' step (the rules' kernel), :meth:`TabularLearner.update
<dqn_transfer.agents.tabular.TabularLearner.update>` (visits, SARSA's next action, the table update, the
entry order), the update statistics' window, the episode sums and an ended episode's values and reset
(:meth:`EpisodeSums.ended_values <dqn_transfer.training.replica.EpisodeSums.ended_values>`,
``TreasureHunts.reset``), in the same order and the same floats, so a run is the same bit for bit
either way (``tests/test_compiled_steps.py``, the reference runs). The ended episodes are logged after
the call, in order (:meth:`Replica.record_episode <dqn_transfer.training.replica.Replica.record_episode>`).
Runs this does not cover stay in Python (:func:`~dqn_transfer.training.trainer.compiled_steps` says
which): exchanges at episode ends, advice, shared replay, games without an observation code.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dqn_transfer.agents.random_streams import draw_uniforms
from dqn_transfer.agents.tabular import DRAWS_PER_AGENT_STEP, TabularLearner
from dqn_transfer.agents.tabular_kernels import choose_action, update_entry
from dqn_transfer.compiled import kernel
from dqn_transfer.enums import Algorithm, RewardMode
from dqn_transfer.envs import rules
from dqn_transfer.envs.game import TreasureHunts
from dqn_transfer.envs.observation_code import encode_rows
from dqn_transfer.training.loop_kernels import EndedEpisodes, UpdateWindow, add_episode_step, epsilon_at


class TabularSteps:
    """The compiled steps of one run (:func:`~dqn_transfer.training.trainer.compiled_steps`), over the
    arrays the learner, the games, the episode sums and the update window own (changed in place)."""

    def __init__(self, learner: TabularLearner, games: TreasureHunts, schedule: Any, sums: Any, window: UpdateWindow):
        self.learner, self.games, self.schedule, self.sums, self.window = learner, games, schedule, sums, window
        code = learner.index.code  # type: ignore[attr-defined]
        rows = learner.num_rows
        self.state_ids = np.zeros(rows, dtype=np.int64)  # the ids of the observations acted on
        self.actions = np.zeros((games.num_replicas, games.num_agents), dtype=np.int64)
        self.entries = np.zeros(1, dtype=np.int64)
        self.draws = np.zeros(DRAWS_PER_AGENT_STEP)
        self.row_maps = code.replica_map[learner.row_replica]
        self.code = code.kernel_arguments()
        self.sarsa = learner.algorithm == Algorithm.sarsa.value
        self.team = games.reward_mode is RewardMode.team
        self.learning = (np.float32(learner.gamma), np.float32(learner.lr))
        self.ended = EndedEpisodes(games.num_replicas, games.num_agents, sums.team_metrics)

    def run(self, step: int, last: int) -> list[tuple[int, int, np.ndarray]]:
        """Joint steps from ``step`` to ``last``; returns each episode that ended on the way, in order, as
        ``(step, replica, values)`` (:meth:`EpisodeSums.ended_values`' row). Its game was restarted."""
        learner, games = self.learner, self.games
        episodes: list[tuple[int, int, np.ndarray]] = []
        while step < last:
            self.entries[0] = learner.num_entries
            step = _run(
                step,
                last,
                self.state_ids,
                self.actions,
                learner.q,
                learner.visits,
                learner.entry_order,
                self.entries,
                learner.epsilon,
                learner.next_action,
                learner.next_state,
                learner.counters["act"],
                learner.counters["next_action"],
                learner.stream_keys["act"],
                learner.stream_keys["next_action"],
                learner.row_replica,
                self.schedule.start,
                self.schedule.end,
                self.schedule.duration,
                self.sums.returns,
                self.sums.lengths,
                self.sums.traps,
                self.sums.team_return,
                self.window.sums,
                self.window.counts,
                self.window.steps,
                self.draws,
                self.ended.rows,
                self.ended.count,
                self.sarsa,
                self.team,
                self.learning,
                self.row_maps,
                self.code,
                *games.rule_constants,
                games.kernel_arrays(),
            )
            games.keep_draws()
            learner.num_entries = int(self.entries[0])
            episodes += self.ended.take()
        return episodes


@kernel
def _run(
    step,
    last,
    state_ids,
    actions,
    q,
    visits,
    entry_order,
    entries,
    epsilon,
    next_action,
    next_state,
    act_counters,
    next_counters,
    act_keys,
    next_keys,
    row_replica,
    eps_start,
    eps_end,
    eps_duration,
    returns,
    lengths,
    traps,
    team_return,
    window_sums,
    window_counts,
    window_steps,
    draws,
    ended,
    num_ended,
    sarsa,
    team,
    learning,
    row_maps,
    code,
    rewards,
    max_steps,
    team_rewards,
    announce,
    game,
):
    """The steps of :meth:`TabularSteps.run` (see the module docstring) from ``step`` to ``last``, or
    until the record of ended episodes is full; returns the step reached."""
    tables, state, out = game[: rules.TABLES_END], game[rules.TABLES_END : rules.STATE_END], game[rules.STATE_END :]
    tables, state, out = rules.Tables(*tables), rules.State(*state), rules.Outcome(*out)
    replicas, agents = state.pos.shape
    rows = replicas * agents
    size, onehot, chests, bits, slots, offsets, position_codes, view_static, view_chest = code
    gamma, lr = learning
    obs = state.obs.reshape(rows, -1)
    while step < last:
        if num_ended[0] + replicas > ended.shape[0]:
            return step
        # 1. act (TabularLearner.act): epsilon-greedy on the ids of the observations, or SARSA's cached action
        state_ids[:] = encode_rows(
            obs, row_maps, size, onehot, chests, bits, slots, offsets, position_codes, view_static, view_chest
        )
        for row in range(rows):
            epsilon[row] = epsilon_at(step, eps_start[row], eps_end[row], eps_duration[row])
            r, a = row // agents, row % agents
            draw_uniforms(act_keys[row], act_counters[r], draws)
            chosen = choose_action(q[row, state_ids[row]], epsilon[row], draws)
            live = state.live[r, a]
            if live and next_action[row] >= 0 and next_state[row] == state_ids[row]:
                chosen = next_action[row]
            if live:
                next_action[row] = -1
            actions[r, a] = chosen if live else 0
        for r in range(replicas):
            act_counters[r] += 1
        # 2. the games' step
        rules.step(tables, state, actions, out, rewards, max_steps, team_rewards, announce)
        step += 1
        # 3. learn (TabularLearner.update) and the update window
        next_ids = encode_rows(
            obs, row_maps, size, onehot, chests, bits, slots, offsets, position_codes, view_static, view_chest
        )
        first = window_steps[0] == 0
        for row in range(rows):
            r, a = row // agents, row % agents
            if not out.acted[r, a]:
                if first:
                    window_sums[0, row] = 0.0
                    window_sums[1, row] = 0.0
                continue
            draw_uniforms(next_keys[row], next_counters[r], draws)
            here, there = state_ids[row], next_ids[row]
            visits[row, here] += 1
            next_action[row] = -1
            bootstrap = -1
            if sarsa:
                bootstrap = choose_action(q[row, there], epsilon[row], draws)
                if not out.truncated[r, a] and not out.terminated[r, a]:
                    next_action[row] = bootstrap
                    next_state[row] = there
            q_sa, td_error = update_entry(
                q, row, here, actions[r, a], out.rewards[r, a], there, out.terminated[r, a], bootstrap, gamma, lr
            )
            if entry_order[row, here] < 0:
                entry_order[row, here] = entries[0]
                entries[0] += 1
            error = np.float64(td_error)
            loss = 0.5 * error * error if abs(error) < 1.0 else abs(error) - 0.5
            if first:
                window_sums[0, row] = loss
                window_sums[1, row] = np.float64(q_sa)
            else:
                window_sums[0, row] += loss
                window_sums[1, row] += np.float64(q_sa)
            window_counts[0, row] += 1
            window_counts[1, row] += 1
        window_steps[0] += 1
        for r in range(replicas):
            next_counters[r] += 1
        # 4. the episodes' sums; an ended episode recorded and its game restarted
        add_episode_step(step, tables, state, out, team, returns, lengths, traps, team_return, ended, num_ended)
    return step
