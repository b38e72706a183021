"""One episode loop: a policy plays a game until every agent is done.

Training-time evaluation, the benchmark's greedy checks and watching a trained team all play
episodes through :func:`play_episode`; only the training loop itself steps the game on its own,
since it runs across episode boundaries on a step budget.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from dqn_transfer.agents.base import Team, Transition
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import Game

# (obs [K, D], live [K]) -> actions [K]; actions of agents that are not live are ignored.
Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]
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


def team_return_of(rewards: np.ndarray, reward_mode: RewardMode) -> float:
    """Team return of one step from the live agents' rewards: their sum (in team mode every agent
    already receives the sum, so it is counted once, not K times)."""
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


def play_episode(
    game: Game,
    policy: Policy,
    rng: np.random.Generator,
    on_step: StepCallback | None = None,
    on_reset: Callable[[], None] | None = None,
) -> EpisodeResult:
    """Reset ``game`` with ``rng`` (it draws the winners of chest ties) and play one episode;
    ``on_reset`` sees the game right after the reset, ``on_step`` after every step."""
    obs = game.reset(rng)
    if on_reset is not None:
        on_reset()
    team_return, length, trapped = 0.0, 0, 0
    agent_returns = np.zeros(game.num_agents)
    chests = game.num_treasures
    cleared_at, return_after_clear = -1, 0.0  # the joint step that emptied the last full chest
    while not game.done:
        live = game.live
        actions = policy(obs, live)
        outcome = game.step(actions)
        next_obs, rewards = outcome.obs, outcome.rewards
        if on_step is not None:
            on_step(
                Transition(obs, actions, rewards, next_obs, outcome.terminated, outcome.truncated, live), outcome.info
            )
        obs = next_obs
        step_return = team_return_of(rewards[live], RewardMode(game.reward_mode))
        team_return += step_return
        agent_returns += rewards
        trapped += int(np.sum(outcome.trap))
        length += 1
        if cleared_at >= 0:
            return_after_clear += step_return
        elif chests and game.treasures_collected == chests:  # a game without chests never clears
            cleared_at = length
    steps_after_clear = length - cleared_at if cleared_at >= 0 else 0
    return EpisodeResult(
        team_return,
        length,
        game.treasures_collected,
        game.treasures_collected / chests if chests else 0.0,
        trapped / game.num_agents,
        steps_after_clear,
        return_after_clear,
        tuple(float(r) for r in agent_returns),
    )


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
