"""One replica of a run: its games, counters, episode in progress, exchange window and logs.

A run batches R independent replicas (``replicas.seeds`` x ``replicas.maps``; one for a lone run), each
a complete run of its own in its own run directory, stepped in lockstep by the loop
(:mod:`dqn_transfer.training.trainer`) with one batched learner, of which ``Replica.learner`` is the
team's view. Here is everything a replica keeps between two steps and what it writes: the episode's
running sums and their TensorBoard points, knowledge exchange inside the team, and its evaluations
(``metrics.jsonl``).
"""

from __future__ import annotations

import json
import logging
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from dqn_transfer.agents import Learner, UpdateStats
from dqn_transfer.agents.schedules import linear_schedules
from dqn_transfer.config import TrainConfig, to_plain
from dqn_transfer.enums import RewardMode
from dqn_transfer.envs import Game, TreasureHuntGame
from dqn_transfer.evaluation.rollout import team_returns_of
from dqn_transfer.evaluation.watch import RecordedEpisode, evaluation_views
from dqn_transfer.exchange import ExchangeMethod
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.loggers import RunLoggers

log = logging.getLogger("dqn_transfer.train")

WHOLE_METRICS = ("team_return", "episode_length", "return_after_clear")  # shown to 0.1 on the console, not 0.01


def exploration_steps(config: TrainConfig) -> int:
    return max(1, int(config.agent.exploration_fraction * config.total_steps))


class EpsilonSchedule(NamedTuple):
    """Per-agent exploration rates (rows of any number of replicas): each decays linearly from
    ``start`` to ``end`` over ``duration`` steps."""

    start: np.ndarray
    end: np.ndarray
    duration: np.ndarray

    def at(self, step: int) -> np.ndarray:
        return linear_schedules(self.start, self.end, self.duration, step)

    @staticmethod
    def joined(schedules: Sequence[EpsilonSchedule]) -> EpsilonSchedule:
        return EpsilonSchedule(*(np.concatenate(column) for column in zip(*schedules)))


class EpisodeSums:
    """Running sums of R replicas' episodes in progress (row r: replica r), as the loop adds each joint
    step of all of them, and each replica's recent team returns (the progress bar's).

    :param replicas: R.
    :param agents: the team's size.
    :param reward_mode: the game's, which says what the team's return is.
    :param team_metrics: what an episode's end logs besides the team's return (the game's ``episode_metrics``).
    """

    def __init__(self, replicas: int, agents: int, reward_mode: RewardMode, team_metrics: Sequence[str]) -> None:
        self.reward_mode = RewardMode(reward_mode)
        self.team_metrics = tuple(team_metrics)
        self.returns = np.zeros((replicas, agents))
        self.lengths = np.zeros((replicas, agents), dtype=np.int64)
        self.traps = np.zeros(replicas, dtype=np.int64)
        self.team_return = np.zeros(replicas)
        self.recent_team_returns: list[deque[float]] = [deque(maxlen=20) for _ in range(replicas)]

    def add(self, rewards: np.ndarray, live: np.ndarray, traps: np.ndarray) -> None:
        """One joint step: ``rewards`` float32, ``live`` (who acted) and ``traps`` bool, all ``[R, K]``."""
        self.returns += rewards
        self.lengths += live
        self.traps += traps.sum(axis=1)
        self.team_return += team_returns_of(rewards, live, self.reward_mode)

    def ended_values(self, ended: np.ndarray, treasures: np.ndarray) -> np.ndarray:
        """The logged values of the episodes of replicas ``ended`` (indices), which just ended with
        ``treasures [R]`` chests emptied: a row each, in the order of
        :func:`~dqn_transfer.training.tensorboard.episode_tags`."""
        team = {"treasures_collected": treasures[ended], "trap_rate": self.traps[ended] / self.returns.shape[1]}
        return np.column_stack(
            [self.returns[ended], self.lengths[ended], self.team_return[ended], *(team[k] for k in self.team_metrics)]
        )


class EpisodeStats:
    """Replica r's row of :class:`EpisodeSums`: its episode in progress."""

    def __init__(self, sums: EpisodeSums, r: int) -> None:
        self.sums, self.r = sums, r

    @property
    def returns(self) -> np.ndarray:
        return self.sums.returns[self.r]

    @property
    def lengths(self) -> np.ndarray:
        return self.sums.lengths[self.r]

    @property
    def traps(self) -> int:
        return int(self.sums.traps[self.r])

    @property
    def team_return(self) -> float:
        return float(self.sums.team_return[self.r])

    @property
    def recent_team_returns(self) -> deque[float]:
        return self.sums.recent_team_returns[self.r]

    def reset(self) -> None:
        self.sums.returns[self.r] = 0.0
        self.sums.lengths[self.r] = 0
        self.sums.traps[self.r] = 0
        self.sums.team_return[self.r] = 0.0

    def state_dict(self) -> dict[str, Any]:
        return {
            "returns": self.returns.tolist(),
            "lengths": self.lengths.tolist(),
            "traps": self.traps,
            "team_return": self.team_return,
            "recent_team_returns": list(self.recent_team_returns),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.sums.returns[self.r] = state["returns"]
        self.sums.lengths[self.r] = state["lengths"]
        self.sums.traps[self.r], self.sums.team_return[self.r] = int(state["traps"]), float(state["team_return"])
        self.recent_team_returns.extend(state["recent_team_returns"])


@dataclass
class Counters:
    """What the loop needs, beyond the learner, to continue exactly where it stopped."""

    step: int = 0
    episodes: int = 0
    evaluations: int = 0
    next_checkpoint: int = 0
    exploration_steps: int = 1  # epsilon's decay horizon, fixed when the run starts (resume may extend total_steps)
    env_rng_state: dict = field(default_factory=dict)


class Replica:
    """One independent run of the batch: its config (own seed and map), run directory, games,
    counters, episode in progress, exchange window and logs. ``learner`` is its team's view of the
    batched learner; ``source`` the checkpoint(s) its transfer targets start from."""

    def __init__(
        self,
        index: int,
        config: TrainConfig,
        run_dir: Path,
        game: Game,
        learner: Learner,
        source: Path | Sequence[Path] | None,
        exchange: ExchangeMethod,
        episodes: EpisodeSums,
        pictures: bool = True,
    ) -> None:
        """
        :param index: r, the replica's place in the batch (its learner rows ``r * K .. r * K + K - 1``)
        :param config: its own config (seed, map)
        :param run_dir: its run directory
        :param game: its game (the map and rules; the loop's game batch plays the episodes)
        :param learner: its team's view of the batched learner
        :param source: the checkpoint(s) its transfer targets start from
        :param exchange: the run's knowledge exchange, which keeps every replica's window
        :param episodes: the batch's episode sums, of which row r is its episode in progress
        :param pictures: evaluations draw their first episode and its Q-values for TensorBoard
        """
        self.index, self.config, self.run_dir = index, config, RunDir(run_dir)
        # Evaluations draw their first episode and its Q-values for TensorBoard (the treasure hunt's map only).
        self.pictures = pictures and isinstance(game, TreasureHuntGame)
        self.game, self.eval_game, self.learner, self.source = game, game.replica(), learner, source
        self.exchange = exchange
        k = game.num_agents
        self.rows = slice(index * k, (index + 1) * k)
        self.counters = Counters(next_checkpoint=config.checkpoint_every, exploration_steps=exploration_steps(config))
        self.transfer_info: dict[str, Any] | None = None
        self.last_eval: dict[str, float] = {}
        self.last_eval_step: int | None = None  # step of the last line in metrics.jsonl
        # Per-agent episodic returns since the last exchange (saved with checkpoints, as the exchange's window).
        self.window_returns: list[np.ndarray] = []
        self.episode = EpisodeStats(episodes, index)
        self.env_rng = np.random.default_rng([config.seed, 17])  # the chest ties of its training games
        self.episode_state: dict[str, Any] | None = None  # a mid-episode checkpoint's game, until the loop starts
        self._logger: RunLoggers | None = None
        self.plain_config = to_plain(config)  # as JSON data, for logs and checkpoint meta (a config never changes)

    @property
    def transferred(self) -> np.ndarray:
        """Which agents started from the transfer source."""
        flags = np.zeros(self.game.num_agents, dtype=bool)
        if self.transfer_info is not None:
            flags[self.transfer_info["targets"]] = True
        return flags

    def epsilon_schedule(self) -> EpsilonSchedule:
        """Each agent's exploration rate: a linear decay over the run's exploration steps, from
        ``transfer.epsilon_start`` for transferred agents."""
        agent, k = self.config.agent, self.game.num_agents
        return EpsilonSchedule(
            np.where(self.transferred, self.config.transfer.epsilon_start, agent.eps_start).astype(np.float64),
            np.full(k, agent.eps_end, dtype=np.float64),
            np.full(k, self.counters.exploration_steps, dtype=np.float64),
        )

    def epsilon(self, step: int) -> np.ndarray:
        return self.epsilon_schedule().at(step)

    # ------------------------------------------------------------------ logs
    def open_logs(self, resume: bool, group: str) -> None:
        """Start the loggers ``logger`` names (W&B's runs of a batch in ``group``); everything logged
        at a resumed checkpoint's step came before it, so only what came after is purged."""
        self._logger = RunLoggers(
            self.config.logger,
            self.run_dir,
            group,
            self.game,
            self.plain_config,
            resume=resume,
            purge_step=self.counters.step + 1 if resume else None,
        )

    def close_logs(self) -> None:
        if self._logger is not None:
            self._logger.close()

    @property
    def logger(self) -> RunLoggers:
        if self._logger is None:
            raise RuntimeError("the replica's logs are not open")
        return self._logger

    # ------------------------------------------------------------------ episodes
    def start_episodes(self) -> None:
        """Put :attr:`game` in the episode the loop continues (a checkpoint's, or a fresh one), from
        which the loop's game batch starts."""
        if self.counters.env_rng_state:  # resumed: continue the episode-reset stream where it stopped
            self.env_rng.bit_generator.state = self.counters.env_rng_state
        if self.episode_state is not None:
            self.game.load_state_dict(self.episode_state["game"], self.env_rng)
            self.episode.load_state_dict(self.episode_state["stats"])
        else:
            self.game.reset(self.env_rng)

    def end_episode(self, values: np.ndarray) -> None:
        """The episode just ended: log its ``values`` (:meth:`EpisodeSums.ended_values`' row) and exchange
        knowledge when due. The loop then starts the next one."""
        self.record_episode(self.counters.step, values)
        self.episode.reset()
        if self.exchange.at_interval and self.counters.episodes % self.config.transfer.exchange_every == 0:
            points = self.exchange.exchange(self.index, self.learner, np.asarray(self.window_returns))
            if points:
                self.logger.scalars(points, self.counters.step)
            self.window_returns.clear()

    def record_episode(self, step: int, values: np.ndarray) -> None:
        """Count and log an episode that ended at ``step`` with ``values`` (:meth:`EpisodeSums.ended_values`'
        row: the agents' returns first, then their lengths, then the team's return)."""
        agents = len(self.episode.returns)
        self.counters.episodes += 1
        self.logger.episode(step, values)
        self.window_returns.append(values[:agents].copy())
        self.episode.recent_team_returns.append(float(values[2 * agents]))

    def log_training(self, sps: float, window_means: UpdateStats | None) -> None:
        """A training-curve point: the mean losses and Q-values of the updates since the last point
        (``window_means``, the agents' rows; None when there was none), epsilon and speed; then the
        logs, with the episodes since the last point, go to the operating system (a watching
        TensorBoard reads them, a killed run keeps them)."""
        logger, step = self.logger, self.counters.step
        points: list[tuple[str, float]] = []
        if window_means is not None:
            points += logger.agent_values("td_loss", window_means.td_loss)
            points += logger.agent_values("q_mean", window_means.q_mean)
        points += [("train/epsilon", float(self.epsilon(step).mean())), ("train/sps", sps)]
        logger.scalars(points, step)  # one event
        logger.flush()

    # ------------------------------------------------------------------ evaluation
    def record_evaluation(self, result: dict[str, Any], pictured: RecordedEpisode | None) -> None:
        """Write a greedy evaluation's record (:func:`~dqn_transfer.evaluation.rollout.summarize` of its
        episodes) to ``metrics.jsonl`` and the logs (the game's headline metrics), with the picture and
        Q-values of its first episode if it was recorded (:attr:`pictures`). The console line is the
        batch's (:func:`evaluation_line`)."""
        step = self.counters.step
        self.counters.evaluations += 1
        self.last_eval = {k: v for k, v in result.items() if k != "agent_returns"}  # team means (checkpoint meta)
        self.last_eval_step = step
        record: dict[str, Any] = {
            "step": step,
            **result,
            "episodes": self.counters.episodes,
            "epsilon": float(self.epsilon(step).mean()),
            "wall_time": time.time(),
        }
        if step == 0 and self.transfer_info is not None:
            record["transfer_source"] = self.transfer_info
        with self.run_dir.metrics.open("a") as stream:
            stream.write(json.dumps(record) + "\n")
        metrics = self.game.headline_metrics
        self.logger.scalars([(f"eval/{key}", result[key]) for key in metrics], step)  # one event
        if pictured is not None:
            self.logger.evaluation_views(*evaluation_views(self.learner, pictured), step)


def metric_text(key: str, value: float) -> str:
    """``value`` of the evaluation metric ``key`` as the console shows it: returns and lengths to 0.1,
    rates to 0.01."""
    return f"{value:.1f}" if key in WHOLE_METRICS else f"{value:.2f}"


def evaluation_line(step: int, results: Sequence[dict[str, Any]], metrics: Sequence[str]) -> str:
    """The console line of one evaluation of a batch: ``metrics`` of its one replica, or of several the
    mean, min and max over them (each replica's own numbers are in its ``metrics.jsonl`` and logs).

    :param step: the evaluation's step.
    :param results: each evaluated replica's record.
    :param metrics: the keys shown, in order (the game's ``headline_metrics``).
    """
    if len(results) == 1:
        shown = " ".join(f"{key} {metric_text(key, results[0][key])}" for key in metrics)
        return f"eval step {step}: {shown}"
    parts = []
    for key in metrics:
        values = [result[key] for result in results]
        low, high = metric_text(key, min(values)), metric_text(key, max(values))
        parts.append(f"{key} {metric_text(key, float(np.mean(values)))} [{low}, {high}]")
    return f"eval step {step}, mean [min, max] of {len(results)} replicas: {' '.join(parts)}"
