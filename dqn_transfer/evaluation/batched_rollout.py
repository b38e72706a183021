"""Greedy evaluation of every replica of a batched learner at once: all their episodes played side by
side as one batch of treasure hunts, with the numbers of :func:`~dqn_transfer.evaluation.rollout.evaluate`.

An evaluation of replica r plays ``episodes`` greedy episodes, episode e reset with
:func:`~dqn_transfer.evaluation.rollout.evaluation_rng` ``(seed_r, step_r, e)`` (which draws the
chest ties) and breaking the ties between equal values with a child of it. Here the ``R x E`` games
are one batch (game ``e * R + r``, so that the learner's ``R * K`` rows answer every episode slot in
one call, ``best_actions_stacked``), stepped until every episode has ended; each game draws from its own
generators in the same order as when played alone, so every record is the one
:func:`~dqn_transfer.evaluation.rollout.evaluate` gives (``tests/test_batched_rollout.py``). Games
that cannot share a batch (another game) are evaluated replica by replica.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from dqn_transfer.agents.base import Learner, Team
from dqn_transfer.agents.state_index import DenseIndex
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import Game
from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts, fit_one_batch
from dqn_transfer.envs.rules import NEEDS_TIE_DRAWS
from dqn_transfer.evaluation import greedy_steps
from dqn_transfer.evaluation.rollout import (
    EpisodeResult,
    EvaluationStopped,
    evaluate,
    evaluation_rng,
    never,
    summarize,
)


def evaluate_replicas(
    learner: Learner | None,
    teams: Sequence[Team],
    games: Sequence[Game],
    episodes: int,
    seeds: Sequence[int],
    steps: Sequence[int],
    firsts: Sequence[EpisodeResult | None],
    stopped: Callable[[], bool] = never,
) -> list[dict[str, Any]]:
    """Each replica's evaluation record, as :func:`~dqn_transfer.evaluation.rollout.evaluate` gives it.

    :param learner: the batched learner whose replicas these are, all of them (rows ``r * K + k``); None:
        play replica by replica through ``teams``
    :param teams: replica r's team (``learner.replica(r)``), for games played one by one
    :param games: replica r's evaluation game (its map and rules; reset here)
    :param episodes: E, the greedy episodes of an evaluation
    :param seeds: replica r's seed, and ``steps``: the training step its evaluation is made at (together
        they seed the episodes)
    :param firsts: replica r's episode 0 as the caller already played it (for a picture), or None
    :param stopped: whether a stop was asked for: then :class:`~dqn_transfer.evaluation.rollout.EvaluationStopped`
        is raised within a joint step (or an episode, replica by replica)
    """
    if learner is None or not fit_one_batch(games):
        return [
            evaluate(team, game, episodes, seed, step, first, stopped)
            for team, game, seed, step, first in zip(teams, games, seeds, steps, firsts)
        ]
    skip_first = [f is not None for f in firsts]
    played = play_greedy_batch(learner, games, episodes, seeds, steps, skip_first, stopped)
    return [summarize(own if first is None else [first, *own[1:]]) for own, first in zip(played, firsts)]


# The most games one batch of an evaluation plays: its setup (maps, generators) is then a fraction of a second,
# so a stop asked for during an evaluation of many episodes ends it within seconds, and its memory is bounded.
GAMES_PER_BATCH = 4096


def play_greedy_batch(
    learner: Learner,
    games: Sequence[TreasureHuntGame],
    episodes: int,
    seeds: Sequence[int],
    steps: Sequence[int],
    skip_first: Sequence[bool],
    stopped: Callable[[], bool] = never,
) -> list[list[EpisodeResult]]:
    """Replica r's greedy episodes ``0..episodes-1`` (episode 0 a placeholder where ``skip_first[r]``),
    played in batches of at most :data:`GAMES_PER_BATCH` games (every replica's episodes
    ``e0..e1-1``); :class:`~dqn_transfer.evaluation.rollout.EvaluationStopped` between two joint steps once
    ``stopped()``."""
    per_batch = max(1, GAMES_PER_BATCH // len(games))
    results: list[list[EpisodeResult]] = [[] for _ in games]
    for first in range(0, episodes, per_batch):
        played = _play_episodes(
            learner, games, range(first, min(first + per_batch, episodes)), seeds, steps, skip_first, stopped
        )
        for own, new in zip(results, played):
            own.extend(new)
    return results


def _play_episodes(
    learner: Learner,
    games: Sequence[TreasureHuntGame],
    numbers: range,
    seeds: Sequence[int],
    steps: Sequence[int],
    skip_first: Sequence[bool],
    stopped: Callable[[], bool],
) -> list[list[EpisodeResult]]:
    """Replica r's greedy episodes ``numbers``, all played in one batch (:func:`play_greedy_batch`)."""
    replicas, agents, episodes = len(games), games[0].num_agents, len(numbers)
    chests, reward_mode = games[0].num_treasures, RewardMode(games[0].reward_mode)
    slots = [(e, r) for e in numbers for r in range(replicas)]  # game g = (e - numbers.start) * R + r
    rngs = [evaluation_rng(seeds[r], steps[r], e) for e, r in slots]
    tie_rngs = [rng.spawn(1)[0] for rng in rngs]  # a child: the parent's stream stays the chest ties'
    hunts = TreasureHunts([games[r].map for _, r in slots], rngs, **games[0].settings())
    skipped = np.array([e == 0 and skip_first[r] for e, r in slots])
    hunts.end(skipped)  # not played here
    count = len(slots)
    rows = count * agents  # row n: agent n % K of game n // K, the learner's row (n // K % R) * K + n % K
    learner_rows = np.tile(np.arange(replicas * agents), episodes)
    dense = isinstance(learner, TabularLearner) and isinstance(learner.index, DenseIndex)
    q = learner.q if dense else np.zeros((1, 1, hunts.num_actions), dtype=np.float32)  # type: ignore[attr-defined]
    code = learner.index.code if dense else None  # type: ignore[attr-defined]
    row_maps = code.replica_map[learner_rows // agents] if code is not None else learner_rows
    code_arguments = code.kernel_arguments() if code is not None else ()
    ids, actions = np.zeros(rows, dtype=np.int64), np.zeros(rows, dtype=np.int64)
    ties, picks = np.zeros(rows, dtype=np.int64), np.zeros(rows, dtype=np.int64)
    sums = np.zeros((count, 5 + agents))  # greedy_steps.step's: returns, length, traps, chests, agents' returns
    cleared_at = np.full(count, -1, dtype=np.int64)  # the length when the last full chest was emptied
    while hunts.live.any():
        if stopped():
            raise EvaluationStopped
        live = hunts.live.reshape(-1)
        if code is not None:
            obs = hunts.obs.reshape(rows, -1)
            greedy_steps.choose(q, learner_rows, row_maps, code_arguments, obs, live, ids, actions, ties)
        else:
            best = learner.best_actions_stacked(hunts.obs.reshape(episodes, replicas * agents, -1)).reshape(rows, -1)
            actions[:] = np.where(live, best.argmax(axis=1), 0)
            ties[:] = np.where(live & (best.sum(axis=1) > 1), best.sum(axis=1), 0)
        for n in np.flatnonzero(ties).tolist():  # each tie drawn as break_ties draws it: the k-th best action
            picks[n] = tie_rngs[n // agents].integers(ties[n])
        if code is None and ties.any():
            tied = np.flatnonzero(ties)
            actions[tied] = np.argmax(np.cumsum(best[tied], axis=1) > picks[tied, None], axis=1)
            ties[:] = 0
        arguments = (q, learner_rows, ids, actions, ties, picks)
        constants = (reward_mode is RewardMode.team, chests, sums, cleared_at, *hunts.rule_constants)
        if greedy_steps.step(*arguments, False, *constants, hunts.kernel_arrays()) == NEEDS_TIE_DRAWS:
            hunts.draw_ties()
            greedy_steps.step(*arguments, True, *constants, hunts.kernel_arrays())
    team_return, return_after_clear, length, trapped, collected = (sums[:, column] for column in range(5))
    agent_returns = sums[:, 5:]
    results: list[list[EpisodeResult]] = [[] for _ in range(replicas)]
    for g, (_, r) in enumerate(slots):
        results[r].append(
            EpisodeResult(
                float(team_return[g]),
                int(length[g]),
                int(collected[g]),
                int(collected[g]) / chests,
                int(trapped[g]) / agents,
                int(length[g]) - int(cleared_at[g]) if cleared_at[g] >= 0 else 0,
                float(return_after_clear[g]),
                tuple(float(value) for value in agent_returns[g]),
            )
        )
    return results
