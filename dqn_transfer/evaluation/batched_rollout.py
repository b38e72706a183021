"""Greedy evaluation of every replica of a batched learner at once: all their episodes played side by
side as one batch of treasure hunts, with the numbers of :func:`~dqn_transfer.evaluation.rollout.evaluate`.

An evaluation of replica r plays ``episodes`` greedy episodes, episode e reset with
:func:`~dqn_transfer.evaluation.rollout.evaluation_rng` ``(seed_r, step_r, e)`` (which draws the
chest ties) and breaking the ties between equal values with a child of it. Here the ``R x E`` games
are one batch (game ``e * R + r``, so that the learner's ``R * K`` rows answer every episode slot in
one call, ``best_actions_stacked``), stepped until every episode has ended; each game draws from its own
generators in the same order as when played alone, so every record is the one
:func:`~dqn_transfer.evaluation.rollout.evaluate` gives (``tests/test_batched_rollout.py``). Games
that cannot share a batch (another game) are played side by side through the one episode loop,
:func:`~dqn_transfer.evaluation.rollout.play_episodes` (:func:`play_looped`); a replica without the
batched learner, or whose picture is asked of a game outside the batch, replica by replica.

The episode 0 of a replica whose evaluation is pictured (TensorBoard's picture, :mod:`~dqn_transfer.evaluation.watch`)
is recorded frame by frame as it is played in the batch, as :func:`~dqn_transfer.evaluation.watch.record_episode`
records it on its own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import lru_cache
from typing import Any, NamedTuple, cast

import numpy as np

from dqn_transfer.agents.base import Learner, Team, break_ties
from dqn_transfer.agents.state_index import DenseIndex
from dqn_transfer.agents.tabular import TabularLearner
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import Game, tie_draws
from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts, fit_one_batch
from dqn_transfer.envs.game_batch import env_batch
from dqn_transfer.evaluation import greedy_steps
from dqn_transfer.evaluation.rollout import (
    BatchPolicy,
    EpisodeResult,
    EvaluationStopped,
    evaluate,
    evaluation_key,
    evaluation_rng,
    greedy_policy,
    never,
    play_batch,
    play_episodes,
    summarize,
)
from dqn_transfer.evaluation.watch import Frame, RecordedEpisode, record_episode


class Evaluation(NamedTuple):
    """One replica's greedy evaluation: its record (:func:`~dqn_transfer.evaluation.rollout.summarize`),
    and its episode 0 frame by frame where it was asked for (a picture), else None."""

    record: dict[str, Any]
    pictured: RecordedEpisode | None


def evaluate_replicas(
    learner: Learner | None,
    teams: Sequence[Team],
    games: Sequence[Game],
    episodes: int,
    seeds: Sequence[int],
    steps: Sequence[int],
    pictured: Sequence[bool],
    stopped: Callable[[], bool] = never,
) -> list[Evaluation]:
    """Each replica's evaluation record, as :func:`~dqn_transfer.evaluation.rollout.evaluate` gives it.

    :param learner: the batched learner whose replicas these are, all of them (rows ``r * K + k``); None:
        play replica by replica through ``teams``
    :param teams: replica r's team (``learner.replica(r)``), for games played one by one
    :param games: replica r's evaluation game (its map and rules; reset here)
    :param episodes: E, the greedy episodes of an evaluation
    :param seeds: replica r's seed, and ``steps``: the training step its evaluation is made at (together
        they seed the episodes)
    :param pictured: whether replica r's episode 0 is recorded frame by frame (a treasure hunt's only)
    :param stopped: whether a stop was asked for: then :class:`~dqn_transfer.evaluation.rollout.EvaluationStopped`
        is raised within a joint step (or an episode, replica by replica)
    """
    if learner is not None and fit_one_batch(games):
        played, recorded = play_greedy_batch(learner, games, episodes, seeds, steps, pictured, stopped)
        return [Evaluation(summarize(own), episode) for own, episode in zip(played, recorded)]
    if learner is not None and not any(pictured):
        played = play_looped(learner, games, episodes, seeds, steps, stopped)
        return [Evaluation(summarize(own), None) for own in played]
    return [
        _evaluate_alone(team, game, episodes, seed, step, picture, stopped)
        for team, game, seed, step, picture in zip(teams, games, seeds, steps, pictured)
    ]


def _evaluate_alone(
    team: Team, game: Game, episodes: int, seed: int, step: int, pictured: bool, stopped: Callable[[], bool]
) -> Evaluation:
    """One replica's evaluation, its episodes played one after another."""
    if not pictured or not isinstance(game, TreasureHuntGame):
        return Evaluation(evaluate(team, game, episodes, seed, step, stopped=stopped), None)
    if stopped():
        raise EvaluationStopped
    rng = evaluation_rng(seed, step, 0)
    episode = record_episode(game, greedy_policy(team, rng), rng)
    return Evaluation(evaluate(team, game, episodes, seed, step, episode.result, stopped), episode)


def play_looped(
    learner: Learner,
    games: Sequence[Game],
    episodes: int,
    seeds: Sequence[int],
    steps: Sequence[int],
    stopped: Callable[[], bool] = never,
) -> list[list[EpisodeResult]]:
    """Replica r's greedy episodes of games the kernels do not play (another PettingZoo game), every
    replica's side by side through :func:`~dqn_transfer.evaluation.rollout.play_episodes` (at most
    :data:`GAMES_PER_BATCH` games at once): the learner chooses for all of them in one pass, each game's
    ties drawn as :func:`~dqn_transfer.evaluation.rollout.greedy_policy` draws them."""
    replicas, agents = len(games), games[0].num_agents
    per_batch = max(1, GAMES_PER_BATCH // replicas)
    results: list[list[EpisodeResult]] = [[] for _ in games]
    for first in range(0, episodes, per_batch):
        numbers = range(first, min(first + per_batch, episodes))
        slots = [(e, r) for e in numbers for r in range(replicas)]  # game g = (e - first) * R + r
        rngs = [evaluation_rng(seeds[r], steps[r], e) for e, r in slots]
        greedy = _greedy_batch(learner, replicas * agents, [rng.spawn(1)[0] for rng in rngs])
        played = _play_side_by_side(_evaluation_games(tuple(games), len(numbers)), greedy, rngs, stopped)
        for (_, r), result in zip(slots, played):
            results[r].append(result)
    return results


def _play_side_by_side(
    games: Sequence[Game], policy: BatchPolicy, rngs: Sequence[np.random.Generator], stopped: Callable[[], bool]
) -> list[EpisodeResult]:
    """One episode of each game (reset with its generator), all side by side: as the batch their env makes of
    them where it makes one (LBF's), else through :func:`~dqn_transfer.evaluation.rollout.play_episodes`."""
    batch = env_batch(games, rngs)
    if batch is None:
        return play_episodes(games, policy, rngs, stopped=stopped)
    batch.reset(np.ones(len(games), dtype=bool))
    return play_batch(batch, games, policy, stopped)


def _greedy_batch(learner: Learner, rows: int, ties: Sequence[np.random.Generator]) -> BatchPolicy:
    """The learner's greedy actions in games whose agents are, E at a time, its ``rows`` rows (game
    ``e * R + r``: replica r's), game g's ties drawn from ``ties[g]``."""

    def greedy(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        best = learner.best_actions_stacked(obs.reshape(-1, rows, obs.shape[-1])).reshape(*live.shape, -1)
        return np.stack([break_ties(*game) for game in zip(best, live, ties)])

    return greedy


@lru_cache(maxsize=4)
def _evaluation_games(games: tuple[Game, ...], episodes: int) -> list[Game]:
    """``episodes`` games of each of ``games`` (game ``e * R + r``: ``games[r]`` itself for e = 0, else a
    replica of it), made once for the evaluations of a run."""
    return [game if e == 0 else game.replica() for e in range(episodes) for game in games]


# The joint steps of dense tables' episodes one kernel call plays before a stop asked for is looked at.
STEPS_PER_CALL = 16
NO_TABLES = np.zeros((1, 1, 1), dtype=np.float32)  # greedy_steps.step's tables where it records no values

# The most games one batch of an evaluation plays: its setup (maps, generators) is then a fraction of a second,
# so a stop asked for during an evaluation of many episodes ends it within seconds, and its memory is bounded.
GAMES_PER_BATCH = 4096


def play_greedy_batch(
    learner: Learner,
    games: Sequence[TreasureHuntGame],
    episodes: int,
    seeds: Sequence[int],
    steps: Sequence[int],
    pictured: Sequence[bool],
    stopped: Callable[[], bool] = never,
) -> tuple[list[list[EpisodeResult]], list[RecordedEpisode | None]]:
    """Replica r's greedy episodes ``0..episodes-1``, played in batches of at most :data:`GAMES_PER_BATCH`
    games (every replica's episodes ``e0..e1-1``), and its episode 0 recorded where ``pictured[r]``;
    :class:`~dqn_transfer.evaluation.rollout.EvaluationStopped` between two joint steps once ``stopped()``."""
    per_batch = max(1, GAMES_PER_BATCH // len(games))
    results: list[list[EpisodeResult]] = [[] for _ in games]
    recorded: list[RecordedEpisode | None] = [None] * len(games)
    for first in range(0, episodes, per_batch):
        numbers = range(first, min(first + per_batch, episodes))
        played, frames = _play_episodes(learner, games, numbers, seeds, steps, pictured, stopped)
        for own, new in zip(results, played):
            own.extend(new)
        for p, g in enumerate(frames.games.tolist()):  # episode 0 of replica g (game g of the first batch)
            recorded[g] = _recorded_episode(games[g], frames, p, results[g][0])
    return results, recorded


def _recorded_episode(
    game: TreasureHuntGame, frames: greedy_steps.Frames, p: int, result: EpisodeResult
) -> RecordedEpisode:
    """Pictured game ``p`` of ``frames`` as :func:`~dqn_transfer.evaluation.watch.record_episode` records it."""
    count = int(frames.num_frames[p])
    cells = np.stack(np.divmod(frames.pos[p, :count], game.size), axis=-1)  # [frames, K, (row, col)]
    live, chest_full = frames.live[p, :count].copy(), frames.chest_full[p, :count].copy()
    times, returns = frames.t[p, :count].tolist(), frames.team_return[p, :count].tolist()
    episode = [Frame(times[i], cells[i], live[i], chest_full[i], returns[i]) for i in range(count)]
    observations = list(zip(frames.obs[p, : count - 1].copy(), frames.acting[p, : count - 1].copy()))
    values = frames.values[p, : count - 1].copy() if frames.values.shape[1] else None
    return RecordedEpisode(game, episode, observations, result, values)


@lru_cache(maxsize=4)
def _evaluation_hunts(games: tuple[TreasureHuntGame, ...], episodes: int) -> TreasureHunts:
    """The batch of ``episodes`` episodes of each of ``games`` (game ``e * R + r``), built once for the
    evaluations of a run (its rule tables take longer to build than a lone run's evaluation to play)."""
    return TreasureHunts([game.map for _ in range(episodes) for game in games], **games[0].settings())


def _play_episodes(
    learner: Learner,
    games: Sequence[TreasureHuntGame],
    numbers: range,
    seeds: Sequence[int],
    steps: Sequence[int],
    pictured: Sequence[bool],
    stopped: Callable[[], bool],
) -> tuple[list[list[EpisodeResult]], greedy_steps.Frames]:
    """Replica r's greedy episodes ``numbers``, all played in one batch (:func:`play_greedy_batch`), and
    the frames of the pictured replicas' episode 0 if it is among them (game g: replica g)."""
    replicas, agents, episodes = len(games), games[0].num_agents, len(numbers)
    chests, reward_mode = games[0].num_treasures, RewardMode(games[0].reward_mode)
    slots = [(e, r) for e in numbers for r in range(replicas)]  # game g = (e - numbers.start) * R + r
    # Game g's generator (evaluation_rng: its chest ties) and a child of it (its greedy ties), packed
    # for the kernels: made there from their entropy, as numpy makes them (no Generator is kept).
    keys = [tie_draws.entropy_words(evaluation_key(seeds[r], steps[r], e)) for e, r in slots]
    entropy = np.zeros((len(slots), max(map(len, keys))), dtype=np.uint64)
    for g, key in enumerate(keys):
        entropy[g, : len(key)] = key
    chest_rng, tie_rng = (np.zeros((len(slots), tie_draws.WORDS), dtype=np.uint64) for _ in range(2))
    tie_draws.seed_with_children(entropy, np.array([len(key) for key in keys]), chest_rng, tie_rng)
    hunts = _evaluation_hunts(tuple(games), episodes)
    hunts.restart(chest_rng)
    count = len(slots)
    rows = count * agents  # row n: agent n % K of game n // K, the learner's row (n // K % R) * K + n % K
    learner_rows = np.tile(np.arange(replicas * agents), episodes)
    dense = isinstance(learner, TabularLearner) and isinstance(learner.index, DenseIndex)
    tables = cast(TabularLearner, learner) if dense else None  # dense tables: the compiled choice
    code = tables.index.code if tables is not None else None  # type: ignore[attr-defined]
    row_maps = code.replica_map[learner_rows // agents] if code is not None else learner_rows
    code_arguments = code.kernel_arguments() if code is not None else ()
    ids, actions = np.zeros(rows, dtype=np.int64), np.zeros(rows, dtype=np.int64)
    sums = np.zeros((count, 5 + agents))  # greedy_steps.step's: returns, length, traps, chests, agents' returns
    cleared_at = np.full(count, -1, dtype=np.int64)  # the length when the last full chest was emptied
    pictured_games = np.array([g for g, (e, r) in enumerate(slots) if e == 0 and pictured[r]], dtype=np.int64)
    frames = greedy_steps.Frames.empty(pictured_games, hunts.max_steps, hunts.state, hunts.num_actions, dense)
    greedy_steps.record_first_frames(frames, hunts.state, sums)
    constants = (reward_mode is RewardMode.team, chests, sums, cleared_at, *hunts.rule_constants)
    playing = True
    while playing:
        if stopped():
            raise EvaluationStopped
        if tables is not None:
            arguments = (tables.q, learner_rows, row_maps, code_arguments, tie_rng, ids, actions, frames)
            playing = greedy_steps.play(*arguments, STEPS_PER_CALL, constants, hunts.kernel_arrays())
        else:
            best = learner.best_actions_stacked(hunts.obs.reshape(episodes, replicas * agents, -1)).reshape(rows, -1)
            greedy_steps.choose_among(best, hunts.live.reshape(-1), actions, tie_rng)
            greedy_steps.step(NO_TABLES, learner_rows, ids, actions, frames, *constants, hunts.kernel_arrays())
            playing = bool(hunts.live.any())
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
    return results, frames
