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
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import Game
from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts, fit_one_batch
from dqn_transfer.evaluation.rollout import (
    EpisodeResult,
    EvaluationStopped,
    evaluate,
    evaluation_rng,
    never,
    summarize,
    team_returns_of,
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
    ties = [rng.spawn(1)[0] for rng in rngs]  # a child: the parent's stream stays the chest ties'
    hunts = TreasureHunts([games[r].map for _, r in slots], rngs, **games[0].settings())
    skipped = np.array([e == 0 and skip_first[r] for e, r in slots])
    hunts.end(skipped)  # not played here
    count = len(slots)
    team_return, return_after_clear = np.zeros(count), np.zeros(count)
    length, trapped = np.zeros(count, dtype=np.int64), np.zeros(count, dtype=np.int64)
    agent_returns = np.zeros((count, agents))
    cleared_at = np.full(count, -1, dtype=np.int64)  # the joint step that emptied the last full chest
    collected = np.zeros(count, dtype=np.int64)
    while hunts.live.any():
        if stopped():
            raise EvaluationStopped
        live = hunts.live
        obs = hunts.obs.reshape(episodes, replicas * agents, -1)
        best = learner.best_actions_stacked(obs).reshape(count * agents, -1)  # [G * K, A]
        actions = np.where(live.reshape(-1), best.argmax(axis=1), 0).astype(np.int64)
        counts = best.sum(axis=1)
        tied = np.flatnonzero(live.reshape(-1) & (counts > 1))
        if tied.size:  # each tie drawn as break_ties draws it: the k-th of the best actions
            picks = [
                int(ties[row // agents].integers(count)) for row, count in zip(tied.tolist(), counts[tied].tolist())
            ]
            actions[tied] = np.argmax(np.cumsum(best[tied], axis=1) > np.array(picks)[:, None], axis=1)
        outcome = hunts.step(actions.reshape(count, agents))
        collected = outcome.episode_treasures
        active = live.any(axis=1)
        step_return = team_returns_of(outcome.rewards, live, reward_mode)
        team_return[active] += step_return[active]
        agent_returns += outcome.rewards  # 0 for agents that are done
        trapped += outcome.trap.sum(axis=1)
        length += active
        after = active & (cleared_at >= 0)
        return_after_clear[after] += step_return[after]
        newly = active & (cleared_at < 0) & (collected == chests)
        cleared_at[newly] = length[newly]
    results: list[list[EpisodeResult]] = [[] for _ in range(replicas)]
    for g, (_, r) in enumerate(slots):
        results[r].append(
            EpisodeResult(
                float(team_return[g]),
                int(length[g]),
                int(collected[g]),
                int(collected[g]) / chests,
                int(trapped[g]) / agents,
                int(length[g] - cleared_at[g]) if cleared_at[g] >= 0 else 0,
                float(return_after_clear[g]),
                tuple(float(value) for value in agent_returns[g]),
            )
        )
    return results
