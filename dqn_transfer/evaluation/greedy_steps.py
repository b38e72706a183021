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

from typing import NamedTuple

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


class Frames(NamedTuple):
    """The pictured games' episodes, frame by frame as the kernels play them (P games of a batch, episodes
    of at most T steps, K agents, k chests): a frame after the reset and after every step a game played.

    ``games [P] int64``: the batch's game of each; ``num_frames [P] int64``: its frames so far. Frame i:
    ``t [P, T + 1]``, ``pos [P, T + 1, K]`` (cells), ``live [P, T + 1, K]``, ``chest_full [P, T + 1, k]``,
    ``team_return [P, T + 1]`` (so far). Step i: ``obs [P, T, K, D]`` what the agents acted on, ``acting
    [P, T, K]`` who acted, ``values [P, T, K, A]`` their Q-values there (a table's; ``[P, 0, K, A]``: not
    recorded).
    """

    games: np.ndarray
    num_frames: np.ndarray
    t: np.ndarray
    pos: np.ndarray
    live: np.ndarray
    chest_full: np.ndarray
    team_return: np.ndarray
    obs: np.ndarray
    acting: np.ndarray
    values: np.ndarray

    @staticmethod
    def empty(games: np.ndarray, steps: int, state: rules.State, actions: int, values: bool) -> Frames:
        """Room for the episodes of ``games`` (the batch's, ``state`` its :class:`~dqn_transfer.envs.rules.State`)."""
        p, (_, agents, dim), chests = len(games), state.obs.shape, state.chest_full.shape[1]
        return Frames(
            games=np.asarray(games, dtype=np.int64),
            num_frames=np.zeros(p, dtype=np.int64),
            t=np.zeros((p, steps + 1), dtype=np.int64),
            pos=np.zeros((p, steps + 1, agents), dtype=np.int64),
            live=np.zeros((p, steps + 1, agents), dtype=bool),
            chest_full=np.zeros((p, steps + 1, chests), dtype=bool),
            team_return=np.zeros((p, steps + 1)),
            obs=np.zeros((p, steps, agents, dim), dtype=np.float32),
            acting=np.zeros((p, steps, agents), dtype=bool),
            values=np.zeros((p, steps if values else 0, agents, actions), dtype=np.float32),
        )


@kernel
def record_first_frames(frames, state, sums):
    """The frame of each pictured game after its reset."""
    for p in range(len(frames.games)):
        record_frame(frames, p, state, sums)


@kernel
def record_frame(frames, p, state, sums):
    """A frame of pictured game ``p`` as it stands."""
    g, i = frames.games[p], frames.num_frames[p]
    frames.t[p, i] = state.t[g]
    frames.pos[p, i] = state.pos[g]
    frames.live[p, i] = state.live[g]
    frames.chest_full[p, i] = state.chest_full[g]
    frames.team_return[p, i] = sums[g, 0]
    frames.num_frames[p] = i + 1


@kernel
def step(
    q,
    learner_rows,
    ids,
    actions,
    frames,
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
    """The games' step with ``actions [G * K]``, recorded in ``frames`` (with the tables ``q`` at the
    learner rows ``learner_rows`` and state ids ``ids`` of the rows, where it records values), and the
    episodes' sums ``sums [G, 5 + K]`` (team return, return after the chests were cleared, length, traps,
    chests collected, each agent's return; ``cleared_at [G]``: the length when the last chest was emptied,
    -1 before)."""
    tables = rules.Tables(*game[: rules.TABLES_END])
    state = rules.State(*game[rules.TABLES_END : rules.STATE_END])
    out = rules.Outcome(*game[rules.STATE_END :])
    games, agents = state.pos.shape
    for p in range(len(frames.games)):
        g, i = frames.games[p], frames.num_frames[p] - 1
        if not state.live[g].any():
            continue
        frames.obs[p, i] = state.obs[g]
        frames.acting[p, i] = state.live[g]
        if frames.values.shape[1] > 0:
            for a in range(agents):
                frames.values[p, i, a] = q[learner_rows[g * agents + a], ids[g * agents + a]]
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
    for p in range(len(frames.games)):
        if out.acted[frames.games[p]].any():
            record_frame(frames, p, state, sums)


@kernel
def play(q, learner_rows, row_maps, code, tie_rng, ids, actions, frames, steps, episodes, game):
    """Up to ``steps`` joint steps of a dense table's greedy episodes (:func:`choose`, then :func:`step`,
    whose arguments from ``team`` to ``announce`` are ``episodes``); returns whether a game is still
    playing."""
    state = rules.State(*game[rules.TABLES_END : rules.STATE_END])
    rows = actions.shape[0]
    obs = state.obs.reshape(rows, -1)
    for _ in range(steps):
        live = state.live.reshape(rows)
        if not live.any():
            return False
        choose(q, learner_rows, row_maps, code, obs, live, ids, actions, tie_rng)
        step(q, learner_rows, ids, actions, frames, *episodes, game)  # type: ignore[call-arg]  # a tuple of 8
    return state.live.any()
