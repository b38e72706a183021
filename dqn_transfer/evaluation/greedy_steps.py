"""The joint steps of a batch of greedy evaluation episodes on the treasure hunt, compiled.

The steps of :func:`~dqn_transfer.evaluation.batched_rollout.play_greedy_batch`: each live agent's best
action (:func:`choose`: from a tabular team's dense tables at the id of its observation,
:class:`~dqn_transfer.agents.state_index.DenseIndex`; :func:`choose_among`: from any learner's best-action
masks), a tie between best actions drawn from its episode's own generator as
:func:`~dqn_transfer.agents.base.break_ties` draws it (the k-th best, ``integers(ties)``, agents in order;
:mod:`~dqn_transfer.envs.tie_draws`), then the games' step and the episodes' sums (:func:`step`), in the
same order and the same floats as an episode played alone (``tests/test_batched_rollout.py``).
"""

from __future__ import annotations

import numpy as np

from dqn_transfer.compiled import kernel
from dqn_transfer.envs import rules, tie_draws
from dqn_transfer.envs.observation_code import encode_rows


@kernel
def pick_best(values, words):
    """The index of the largest of ``values``; where several are largest, the k-th of them with
    ``k = integers(count)`` drawn from the packed generator ``words``."""
    best, count = values.max(), 0
    for a in range(len(values)):
        if values[a] == best:
            count += 1
    pick = 0 if count == 1 else tie_draws.integers(words, count)
    for a in range(len(values)):
        if values[a] == best:
            if pick == 0:
                return a
            pick -= 1
    return 0


@kernel
def choose(q, learner_rows, row_maps, code, obs, live, ids, actions, tie_rng):
    """Each live row's best action of ``q [rows, S, A]`` (row ``learner_rows[n]``) at the id of its
    observation ``obs [N, D]``, into ``actions [N]`` (0 for a row that is not live); row n's ties drawn
    from its game's generator ``tie_rng[n // K]`` (``K = N // len(tie_rng)``)."""
    ids[:] = encode_rows(obs, row_maps, *code)
    agents = len(actions) // len(tie_rng)
    for n in range(len(actions)):
        actions[n] = pick_best(q[learner_rows[n], ids[n]], tie_rng[n // agents]) if live[n] else 0


@kernel
def choose_among(best, live, actions, tie_rng):
    """:func:`choose` from best-action masks ``best [N, A] bool`` (a learner's ``best_actions``)."""
    agents = len(actions) // len(tie_rng)
    for n in range(len(actions)):
        actions[n] = pick_best(best[n], tie_rng[n // agents]) if live[n] else 0


@kernel
def step(actions, team, chests, sums, cleared_at, rewards, max_steps, team_rewards, announce, game):
    """The games' step with ``actions [G * K]`` and the episodes' sums ``sums [G, 5 + K]`` (team return,
    return after the chests were cleared, length, traps, chests collected, each agent's return;
    ``cleared_at [G]``: the length when the last chest was emptied, -1 before)."""
    tables = rules.Tables(*game[: rules.TABLES_END])
    state = rules.State(*game[rules.TABLES_END : rules.STATE_END])
    out = rules.Outcome(*game[rules.STATE_END :])
    games, agents = state.pos.shape
    rules.step(tables, state, actions.reshape(games, agents), out, rewards, max_steps, team_rewards, announce)
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
