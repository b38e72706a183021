"""The joint steps of a batch of greedy evaluation episodes of a tabular team on the treasure hunt, compiled.

The steps of :func:`~dqn_transfer.evaluation.batched_rollout.play_greedy_batch` for a learner with dense
tables (:class:`~dqn_transfer.agents.state_index.DenseIndex`): each live agent's best actions from its
table at the id of its observation, the game's step and the episodes' sums, in the same order and the same
floats. Ties between best actions are still drawn in Python, from each episode's own generator and in the
same order (:func:`choose` stops for them), so every record is the one the Python steps give
(``tests/test_batched_rollout.py``).
"""

from __future__ import annotations

import numpy as np

from dqn_transfer.compiled import kernel
from dqn_transfer.envs import rules
from dqn_transfer.envs.observation_code import encode_rows


@kernel
def choose(q, learner_rows, row_maps, code, obs, live, ids, actions, ties):
    """Each live row's best action of ``q [rows, S, A]`` (row ``learner_rows[n]``) at the id of its
    observation ``obs [N, D]``, into ``actions [N]`` (0 for a row that is not live); ``ties [N]``: how many
    actions tie for the best (0: none, the action is set). Returns how many rows tie."""
    ids[:] = encode_rows(obs, row_maps, *code)
    tied = 0
    for n in range(len(actions)):
        actions[n], ties[n] = 0, 0
        if not live[n]:
            continue
        values = q[learner_rows[n], ids[n]]
        best, count = values.max(), 0
        for a in range(len(values)):
            if values[a] == best:
                count += 1
                if count == 1:
                    actions[n] = a
        if count > 1:
            ties[n] = count
            tied += 1
    return tied


@kernel
def step(
    q,
    learner_rows,
    ids,
    actions,
    ties,
    picks,
    resume,
    team,
    chests,
    sums,
    cleared_at,
    rewards,
    max_steps,
    team_rewards,
    announce,
    game,
):
    """The tied rows' actions (the ``picks[n]``-th of their best), the games' step and the episodes' sums
    ``sums [G, 5 + K]`` (team return, return after the chests were cleared, length, traps, chests
    collected, each agent's return; ``cleared_at [G]``: the length when the last chest was emptied, -1
    before). Returns :data:`~dqn_transfer.envs.rules.NEEDS_TIE_DRAWS` (nothing else changed: draw the chest
    ties, call again with ``resume``) or :data:`~dqn_transfer.envs.rules.DONE`."""
    tables = rules.Tables(*game[: rules.TABLES_END])
    state = rules.State(*game[rules.TABLES_END : rules.STATE_END])
    out = rules.Outcome(*game[rules.STATE_END :])
    games, agents = state.pos.shape
    for n in range(len(actions)):
        if ties[n] > 0:
            values = q[learner_rows[n], ids[n]]
            best, seen = values.max(), 0
            for a in range(len(values)):
                if values[a] == best:
                    if seen == picks[n]:
                        actions[n] = a
                    seen += 1
    status = rules.step(
        tables, state, actions.reshape(games, agents), out, resume, rewards, max_steps, team_rewards, announce
    )
    if status != rules.DONE:
        return status
    for g in range(games):
        for a in range(agents):
            sums[g, 5 + a] += np.float64(out.rewards[g, a])
            sums[g, 3] += out.trap[g, a]
        if not out.acted[g].any():
            continue
        step_return = rules.team_step_return(out, g, team)
        sums[g, 0] += step_return
        sums[g, 2] += 1
        if cleared_at[g] >= 0:
            sums[g, 1] += step_return
        sums[g, 4] = state.treasures_collected[g]
        if cleared_at[g] < 0 and state.treasures_collected[g] == chests:
            cleared_at[g] = sums[g, 2]
    return rules.DONE
