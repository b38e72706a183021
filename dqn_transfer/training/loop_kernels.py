"""What the compiled training steps (:mod:`~dqn_transfer.training.tabular_steps`,
:mod:`~dqn_transfer.training.dqn_steps`) share: the update statistics' window, the record of ended
episodes, the exploration schedule, and one joint step's episode sums, with an ended episode's values
and restart, as a kernel.

Each is the Python loop's statement compiled, in the same order and the same floats
(:meth:`EpisodeSums.add <dqn_transfer.training.replica.EpisodeSums.add>`,
:meth:`EpisodeSums.ended_values <dqn_transfer.training.replica.EpisodeSums.ended_values>`,
``TreasureHunts.reset``), so a run is the same bit for bit either way.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dqn_transfer.compiled import kernel
from dqn_transfer.envs import rules

EPISODES_PER_CALL = 4096  # the most ended episodes one call records before the caller logs them


class UpdateWindow:
    """Each row's mean ``td_loss`` and ``q_mean`` over the updates since the last training-curve point,
    as running sums: the first step's values (NaN, no update, as 0), then each later step's added, and
    the count of updates -- the floats of ``numpy.nanmean`` over the window's rows."""

    def __init__(self, rows: int) -> None:
        self.sums = np.zeros((2, rows))  # td_loss, q_mean
        self.counts = np.zeros((2, rows), dtype=np.int64)
        self.steps = np.zeros(1, dtype=np.int64)  # steps in the window (an array: the kernels add to it)

    def add(self, td_loss: np.ndarray, q_mean: np.ndarray) -> None:
        """One step's statistics (NaN where a row had no update)."""
        values = np.stack([td_loss, q_mean]).astype(np.float64)
        known = ~np.isnan(values)
        values[~known] = 0.0
        self.sums[:] = values if self.steps[0] == 0 else self.sums + values
        self.counts += known
        self.steps[0] += 1

    def means(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(td_loss, q_mean)`` per row (NaN for a row without an update), None for an empty window;
        the window then starts again."""
        if self.steps[0] == 0:
            return None
        with np.errstate(invalid="ignore", divide="ignore"):
            means = self.sums / self.counts
        self.sums[:] = 0.0
        self.counts[:] = 0
        self.steps[0] = 0
        return means[0], means[1]


class EndedEpisodes:
    """The record a kernel writes of the episodes that ended during a call: per episode its step, its
    replica, then :meth:`EpisodeSums.ended_values`' row (the agents' returns, their lengths, the team's
    return, the treasures collected, the trap rate).

    :param replicas: R, the games stepped (a step can end all their episodes at once)
    :param agents: the team's size
    :param team_metrics: the episode sums' ``team_metrics``, which must be the treasure hunt's
    """

    def __init__(self, replicas: int, agents: int, team_metrics: Any) -> None:
        if tuple(team_metrics) != ("treasures_collected", "trap_rate"):
            raise ValueError(f"the compiled steps log the treasure hunt's episode metrics, not {team_metrics}")
        self.rows = np.zeros((max(EPISODES_PER_CALL, replicas), 2 + 2 * agents + 3))
        self.count = np.zeros(1, dtype=np.int64)

    def take(self) -> list[tuple[int, int, np.ndarray]]:
        """The recorded episodes as ``(step, replica, values)``, in order; the record then starts again."""
        taken = [(int(row[0]), int(row[1]), row[2:].copy()) for row in self.rows[: self.count[0]]]
        self.count[0] = 0
        return taken


@kernel
def epsilon_at(step, start, end, duration):
    """:func:`~dqn_transfer.agents.schedules.linear_schedules` of one row at ``step``, compiled (the same floats)."""
    fraction = min(max(step / duration, 0.0), 1.0) if duration > 0 else 1.0
    return start + fraction * (end - start)


@kernel
def add_episode_step(step, tables, state, out, team, returns, lengths, traps, team_return, ended, num_ended):
    """One joint step, ending at ``step``, added to the episodes' sums (``EpisodeSums.add``); an ended
    episode is recorded at ``ended[num_ended[0]]`` (:class:`EndedEpisodes`), its sums zeroed and its game
    restarted (``TreasureHunts.reset``)."""
    replicas, agents = state.pos.shape
    for r in range(replicas):
        for a in range(agents):
            returns[r, a] += np.float64(out.rewards[r, a])
            lengths[r, a] += out.acted[r, a]
            traps[r] += out.trap[r, a]
        team_return[r] += rules.team_step_return(out, r, team)
        if not out.ended[r]:
            continue
        record = ended[num_ended[0]]
        num_ended[0] += 1
        record[0], record[1] = step, r
        for a in range(agents):
            record[2 + a] = returns[r, a]
            record[2 + agents + a] = lengths[r, a]
            returns[r, a] = 0.0
            lengths[r, a] = 0
        record[2 + 2 * agents] = team_return[r]
        record[3 + 2 * agents] = state.treasures_collected[r]
        record[4 + 2 * agents] = traps[r] / agents
        team_return[r] = 0.0
        traps[r] = 0
        rules.reset_replica(tables, state, r)
