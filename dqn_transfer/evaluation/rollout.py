"""One episode loop: games played side by side by a policy until every agent of each is done.

:func:`play_episodes` is the loop; greedy evaluations of games the compiled kernels do not play (another
PettingZoo game: all replicas' episodes side by side, :mod:`~dqn_transfer.evaluation.batched_rollout`),
a team's evaluation on its own, the bounds' policies and watching a trained team play through it
(:func:`play_episode`: one game). The treasure hunt's batched evaluations run the same steps compiled
(:mod:`~dqn_transfer.evaluation.greedy_steps`); the training loop steps its games on its own, since it
runs across episode boundaries on a step budget.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from dqn_transfer.agents.base import Team, Transition
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import Game
from dqn_transfer.envs.batch import GameBatch

# (obs [K, D], live [K]) -> actions [K]; actions of agents that are not live are ignored.
Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]
# (obs [G, K, D], live [G, K]) -> actions [G, K] of G games played side by side (a game's row is ignored
# once its episode is over).
BatchPolicy = Callable[[np.ndarray, np.ndarray], np.ndarray]
# Called after every step with the joint transition and the game's info dict.
StepCallback = Callable[[Transition, dict], None]
EVALUATION_STREAM = 1_000_003  # keeps evaluation episodes' generators apart from every other stream of a seed


class EvaluationStopped(Exception):
    """A stop was asked for (SIGINT / SIGTERM) while an evaluation was played: it ends unfinished, unrecorded."""


def never() -> bool:
    """The ``stopped`` of an evaluation nothing stops."""
    return False


class EpisodeResult(NamedTuple):
    team_return: float
    length: int  # joint steps
    treasures_collected: int
    success_rate: float  # treasures collected / chests on the map
    trap_rate: float  # agents that ended in a trap / agents
    # Joint steps played after the step that emptied the map's last full chest, and the team return of
    # those steps: only there could an announcement of a taken chest still reach a playing agent. 0 when
    # the episode ended with that step or never emptied every chest.
    steps_after_clear: int = 0
    return_after_clear: float = 0.0
    # Each agent's return: the sum of the rewards it received (0 once it is done). In team mode every
    # live agent receives the team's reward, so each equals the team return of its live steps.
    agent_returns: tuple[float, ...] = ()


def team_return_of(rewards: np.ndarray, live: np.ndarray, reward_mode: RewardMode) -> float:
    """Team return of one step from the rewards ``[K]`` of the agents ``live [K]`` before it: their sum (in
    team mode every agent already receives the sum, so it is counted once, not K times)."""
    rewards = rewards[live]
    return float(rewards.max() if reward_mode is RewardMode.team and rewards.size else rewards.sum())


def team_returns_of(rewards: np.ndarray, live: np.ndarray, reward_mode: RewardMode) -> np.ndarray:
    """:func:`team_return_of` of every row of ``rewards [N, K]`` float32 at once, its live agents those of
    ``live [N, K]``: ``float64 [N]``, 0 for a row with none. The same floats for fewer than 8 agents;
    beyond, numpy's pairwise sum may round the last bit of fractional rewards differently."""
    if RewardMode(reward_mode) is RewardMode.team:
        step = np.where(live, rewards, -np.inf).max(axis=1)
    else:
        step = np.where(live, rewards, np.float32(0.0)).sum(axis=1)
    return np.where(live.any(axis=1), step, 0.0).astype(np.float64)


def greedy_policy(learner: Team, episode_rng: np.random.Generator | None = None) -> Policy:
    """The learner's greedy actions; consumes none of its random numbers. Ties between equal values are
    drawn from a child of ``episode_rng`` (the generator the episode resets with, whose own stream a
    child leaves untouched): two learners with equal values evaluated on the same episode play the
    same moves. Without it, ties go to the first best action."""
    ties = episode_rng.spawn(1)[0] if episode_rng is not None else None
    return lambda obs, live: learner.greedy(obs, live, ties)


class EpisodeTally:
    """One episode's sums as it is played, its :class:`EpisodeResult` at the end."""

    def __init__(self, num_agents: int) -> None:
        self.team_return, self.length, self.trapped = 0.0, 0, 0
        self.agent_returns = np.zeros(num_agents)
        self.cleared_at, self.return_after_clear = -1, 0.0  # the joint step that emptied the last full chest

    def add(self, game: Game, rewards: np.ndarray, live: np.ndarray, trap: np.ndarray) -> None:
        """The step ``game`` just played: its ``rewards``, who was ``live`` before it, who fell in a trap."""
        step_return = team_return_of(rewards, live, game.reward_mode)
        self.team_return += step_return
        self.agent_returns += rewards
        self.trapped += int(np.sum(trap))
        self.length += 1
        if self.cleared_at >= 0:
            self.return_after_clear += step_return
        elif game.num_treasures and game.treasures_collected == game.num_treasures:  # no chests: never cleared
            self.cleared_at = self.length

    def result(self, game: Game) -> EpisodeResult:
        chests = game.num_treasures
        return EpisodeResult(
            self.team_return,
            self.length,
            game.treasures_collected,
            game.treasures_collected / chests if chests else 0.0,
            self.trapped / game.num_agents,
            self.length - self.cleared_at if self.cleared_at >= 0 else 0,
            self.return_after_clear,
            tuple(float(r) for r in self.agent_returns),
        )


def play_episodes(
    games: Sequence[Game],
    policy: BatchPolicy,
    rngs: Sequence[np.random.Generator],
    on_step: Callable[[int, Transition, dict], None] | None = None,
    on_reset: Callable[[], None] | None = None,
    stopped: Callable[[], bool] = never,
) -> list[EpisodeResult]:
    """Reset game g with ``rngs[g]`` (it draws the winners of chest ties) and play one episode of every
    game side by side: at each joint step ``policy`` chooses for all of them at once, and each game still
    playing steps. ``on_reset`` sees the games right after their reset, ``on_step(g, transition, info)``
    game g after each of its steps; :class:`EvaluationStopped` before a joint step once ``stopped()``."""
    obs = [game.reset(rng) for game, rng in zip(games, rngs)]
    if on_reset is not None:
        on_reset()
    tallies = [EpisodeTally(game.num_agents) for game in games]
    while not all(game.done for game in games):
        if stopped():
            raise EvaluationStopped
        live = [game.live for game in games]
        actions = policy(np.stack(obs), np.stack(live))
        for g, game in enumerate(games):
            if game.done:
                continue
            outcome = game.step(actions[g])
            if on_step is not None:
                transition = Transition(
                    obs[g], actions[g], outcome.rewards, outcome.obs, outcome.terminated, outcome.truncated, live[g]
                )
                on_step(g, transition, outcome.info)
            tallies[g].add(game, outcome.rewards, live[g], outcome.trap)
            obs[g] = outcome.obs
    return [tally.result(game) for tally, game in zip(tallies, games)]


def play_batch(
    batch: GameBatch, games: Sequence[Game], policy: BatchPolicy, stopped: Callable[[], bool] = never
) -> list[EpisodeResult]:
    """:func:`play_episodes` of ``games`` stepped as one ``batch`` (each game just reset, the batch made of
    them then): one episode of every game, each one's tally as :func:`play_episodes` keeps it. A batch steps
    all its games, so a game whose episode has ended is reset and played on until the last has ended, those
    steps not counted (its episode's generators are not drawn from afterwards)."""
    tallies = [EpisodeTally(game.num_agents) for game in games]
    ended = np.zeros(len(games), dtype=bool)
    while not ended.all():
        if stopped():
            raise EvaluationStopped
        live = batch.live
        step = batch.step(policy(batch.obs, live))
        for g in np.flatnonzero(~ended).tolist():
            tallies[g].add(games[g], step.rewards[g], live[g], step.trap[g])
        ended |= step.episode_end
        if not ended.all():  # after the last episode's end no game plays on
            batch.reset(step.episode_end)
    return [tally.result(game) for tally, game in zip(tallies, games)]


def play_episode(
    game: Game,
    policy: Policy,
    rng: np.random.Generator,
    on_step: StepCallback | None = None,
    on_reset: Callable[[], None] | None = None,
) -> EpisodeResult:
    """:func:`play_episodes` of one game: reset it with ``rng`` and play one episode with ``policy``;
    ``on_reset`` sees the game right after the reset, ``on_step`` after every step."""
    step = None if on_step is None else lambda _, transition, info: on_step(transition, info)
    return play_episodes([game], lambda obs, live: policy(obs[0], live[0])[None], [rng], step, on_reset)[0]


def evaluation_rng(seed: int, step: int, episode: int) -> np.random.Generator:
    """The generator of one evaluation episode: from (run seed, training step of the evaluation,
    episode) alone, so independent of training history, of how many evaluations came before (the
    evaluation at step N is the same for every ``eval_every`` that reaches N) and of a resume."""
    return np.random.default_rng(evaluation_key(seed, step, episode))


def evaluation_key(seed: int, step: int, episode: int) -> list[int]:
    """The entropy of :func:`evaluation_rng`."""
    return [seed, EVALUATION_STREAM, step, episode]


def evaluate(
    learner: Team,
    game: Game,
    episodes: int,
    seed: int,
    step: int,
    first: EpisodeResult | None = None,
    stopped: Callable[[], bool] = never,
) -> dict[str, Any]:
    """Greedy episodes, each seeded by :func:`evaluation_rng`, as :func:`summarize` records them; raises
    :class:`EvaluationStopped` when ``stopped()`` says so before an episode.

    :param learner: the team, played greedily.
    :param game: the game the episodes are played in (reset by each).
    :param episodes: how many episodes.
    :param seed: the run's seed; with ``step`` and the episode's number it seeds each episode.
    :param step: the training step the evaluation is made at (0 for the run's start).
    :param first: episode 0 as the caller already played it (e.g. recorded for a picture), not played
        again.
    :param stopped: whether a stop was asked for (a long evaluation must not outlast SLURM's grace period).
    """
    results = [] if first is None else [first]
    for episode in range(len(results), episodes):
        if stopped():
            raise EvaluationStopped
        rng = evaluation_rng(seed, step, episode)
        results.append(play_episode(game, greedy_policy(learner, rng), rng))
    return summarize(results)


def summarize(results: Sequence[EpisodeResult]) -> dict[str, Any]:
    """An evaluation's record: the team's means over its episodes (floats, in episode order) and
    ``agent_returns``, each agent's mean return (a list of K floats, agent order)."""
    return {
        "team_return": float(np.mean([r.team_return for r in results])),
        "success_rate": float(np.mean([r.success_rate for r in results])),
        "trap_rate": float(np.mean([r.trap_rate for r in results])),
        "episode_length": float(np.mean([r.length for r in results])),
        # Episodes still played after the last full chest was emptied (see EpisodeResult), and the
        # team return of those steps per episode (0 for the others).
        "after_clear_rate": float(np.mean([r.steps_after_clear > 0 for r in results])),
        "return_after_clear": float(np.mean([r.return_after_clear for r in results])),
        "agent_returns": [float(r) for r in np.mean([r.agent_returns for r in results], axis=0)],
    }
