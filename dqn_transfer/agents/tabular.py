"""Tabular SARSA (the study's base learner) and Q-learning for K agents, in R replicas, as arrays.

Each agent has its own Q-table over the exact observations (float32 vectors) of its game. A replica's
observations have dense ids (its agents share the game): the game's own numbering when it offers one
and the tables fit (the treasure hunt's, :mod:`dqn_transfer.envs.observation_code`: every state's row
allocated at once), else the order they are first met (:mod:`~dqn_transfer.agents.state_index`). So
every agent's table is a row of one array ``Q [R * K, S, A]`` and acting or updating all agents of all
replicas is a few array operations, the choice and the update compiled loops over rows
(:mod:`~dqn_transfer.agents.tabular_kernels`). An observation is worth
0 for every action until its agent updates it, unless the agent has *fallbacks*: tables from another
agent (set by transfer), each looked up on a projection of the observation, in turn; the first that
knows it gives the entry's starting values. An agent's table (what its checkpoint holds) is the
entries it has updated, in the order it first updated them.

Update of agent i for a transition ``(s, a, r, s')``, learning rate ``alpha = lr``::

    y = r                                  if s' is terminal
    y = r + gamma * Q(s', a')              SARSA: a' epsilon-greedy on Q(s', .), played next
    y = r + gamma * max_a' Q(s', a')       Q-learning
    Q(s, a) <- Q(s, a) + alpha * (y - Q(s, a))

A truncated episode (time limit) bootstraps like any non-terminal step. SARSA picks ``a'`` at
update time with the epsilon of the last ``act``, and the next ``act`` on ``s'`` returns that same
action, so the update follows the policy actually played (on-policy).

Random numbers are counter-based (:mod:`~dqn_transfer.agents.random_streams`): every agent-step takes
three uniforms (explore?, which random action, which of tied best actions) keyed by the replica's
seed, the purpose (acting, SARSA's ``a'``, learning from team-mates), a per-replica counter and the
agent. So all agents draw at once, replica (seed s) is the lone run of seed s, and a checkpoint needs
only the counters.

Each agent also counts its visits of each state (its updates there on its own transitions), which the
exchanges by visit counts read (:mod:`~dqn_transfer.agents.visit_exchange`: confidence merging, advice).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from dqn_transfer.agents.base import (
    Experience,
    KnowledgeExchange,
    Learner,
    ObsLayout,
    Team,
    TeamShape,
    Transition,
    UpdateStats,
    check_tensor_shape,
)
from dqn_transfer.agents.dqn_update import huber
from dqn_transfer.agents.random_streams import stream_keys, uniforms
from dqn_transfer.agents.replicas import team_view
from dqn_transfer.agents.state_index import DenseIndex, MetOrderIndex, StateCode, StateIndex
from dqn_transfer.agents.tabular_kernels import epsilon_greedy_rows, update_in_order, update_rows
from dqn_transfer.agents.visit_exchange import AdviceRules, VisitExchange, advised_actions, confident_merge
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm

_NO_ACTION = -1  # empty slot of the SARSA next-action cache

# The purposes of the counter-based draws (one stream each).
ACT_STREAM, NEXT_ACTION_STREAM, LEARN_FROM_STREAM = 1, 2, 3
DRAWS_PER_AGENT_STEP = 3  # explore?, a random action, a pick among tied best actions
# Dense tables (every id of the game's code allocated at once) up to this many bytes for all rows; beyond,
# the ids of the observations met (a 6-agent deliberative team on 10x10 with 6 chests has 44,800 states).
DENSE_TABLES_MAX_BYTES = 256 * 2**20


def table_bytes_per_state(num_actions: int) -> int:
    """Bytes a row's arrays hold per state: its Q-values (float32), entry order (int32) and visits (int64)."""
    return 4 * num_actions + 4 + 8


def fallback_names(level: int) -> tuple[str, str, str]:
    """The tensor names of fallback table ``level`` (0 is looked up first): keys, values, projection."""
    tag = "fallback" if level == 0 else f"fallback{level}"
    return f"{tag}_keys", f"{tag}_values", f"{tag}_projection"


def fallback_tables(tensors: Mapping[str, np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The fallback tables in ``tensors``, in lookup order (levels 0, 1, ... up to the first missing)."""
    tables: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    while True:
        names = fallback_names(len(tables))
        present = [name for name in names if name in tensors]
        if not present:
            return tables
        if len(present) != len(names):
            raise ValueError(f"fallback table is incomplete: has only {present}")
        keys, values, projection = (np.asarray(tensors[name]) for name in names)
        tables.append((keys, values, projection))


class _Fallback:
    """A read-only Q-table looked up on ``obs[projection]``."""

    def __init__(self, keys: np.ndarray, values: np.ndarray, projection: np.ndarray) -> None:
        self.keys = np.ascontiguousarray(keys, dtype=np.float32)
        self.values = np.ascontiguousarray(values, dtype=np.float32)
        self.projection = np.asarray(projection, dtype=np.int64)
        self.table = {key.tobytes(): n for n, key in enumerate(self.keys)}

    def rows_of(self, obs: np.ndarray) -> np.ndarray:
        """The row of ``values`` each observation ``obs [N, D]`` finds (-1: none)."""
        keys = np.ascontiguousarray(obs[:, self.projection], dtype=np.float32)
        return np.array([self.table.get(key.tobytes(), -1) for key in keys], dtype=np.int64)


def check_fallback(
    keys: np.ndarray, values: np.ndarray, projection: np.ndarray, obs_dim: int, num_actions: int
) -> None:
    """``ValueError`` unless a fallback table fits observations of ``obs_dim`` values and ``num_actions``."""
    if keys.ndim != 2 or projection.shape != (keys.shape[1],) or values.shape != (len(keys), num_actions):
        raise ValueError(
            f"fallback table is malformed: keys {list(keys.shape)}, values {list(values.shape)}, "
            f"projection {list(projection.shape)}, {num_actions} actions"
        )
    if projection.size and (projection.min() < 0 or projection.max() >= obs_dim):
        raise ValueError(f"fallback projection points outside the {obs_dim} observation columns")


class TabularLearner(Learner, KnowledgeExchange, VisitExchange):
    """K Q-tables updated by SARSA or Q-learning (see the module docstring), in R replicas: ``R * K``
    tables, row ``r * K + k``, replica r exploring with its own seed's draws (exactly the team a lone
    learner of its seed would be)."""

    def __init__(
        self,
        num_agents: int,
        obs_layout: ObsLayout,
        num_actions: int,
        hp: AgentConfig,
        *,
        seed: int | Sequence[int] = 0,
        code: StateCode | None = None,
    ) -> None:
        """
        :param num_agents: K, the agents of the team (one table each)
        :param obs_layout: the observation's named segments ``[(name, size), ...]``
        :param num_actions: A, the discrete actions
        :param hp: the hyperparameters, documented on :class:`~dqn_transfer.config.AgentConfig`:
            ``algorithm`` (sarsa | qlearning), ``lr`` (alpha, the step size of the table update), ``gamma``
        :param seed: fixes exploration and tie-breaking; a list of R seeds makes R replicas
        :param code: the game's numbering of its observations (None: it has none), used when the dense
            tables fit in :data:`DENSE_TABLES_MAX_BYTES`
        """
        algorithm = Algorithm(hp.algorithm)
        if not algorithm.is_tabular:
            raise ValueError(f"TabularLearner trains sarsa or qlearning, not {algorithm.value}")
        TeamShape.__init__(self, algorithm, num_agents, obs_layout, num_actions)
        self.lr = hp.lr
        self.gamma = hp.gamma
        seeds = [int(seed)] if isinstance(seed, (int, np.integer)) else [int(s) for s in seed]
        if min(seeds) < 0:
            raise ValueError(f"seeds must be non-negative, got {seeds}")
        self.num_replicas = replicas = len(seeds)
        self.num_rows = rows = replicas * num_agents
        self.row_seed = np.repeat(np.asarray(seeds, dtype=np.int64), num_agents)
        self.row_replica = np.repeat(np.arange(replicas), num_agents)
        self.row_agent = np.tile(np.arange(num_agents), replicas)
        dense = code is not None and rows * code.num_ids * table_bytes_per_state(num_actions) <= DENSE_TABLES_MAX_BYTES
        self.index: StateIndex = (
            DenseIndex(code, self.row_replica)
            if code is not None and dense
            else MetOrderIndex(replicas, self.obs_dim, self.row_replica)
        )
        states = self.index.capacity
        self.q = np.zeros((rows, states, num_actions), dtype=np.float32)
        # Entry order: when the agent first updated it (-1: not in its table, the value is a start value).
        self.entry_order = np.full((rows, states), -1, dtype=np.int32)
        self.num_entries = 0  # entries entered so far, all rows together (the next entry's order)
        # Visits: how many of its own transitions each agent has learned from in each state (what the
        # exchanges by visit counts weigh, agents/visit_exchange.py); team-mates' transitions do not count.
        self.visits = np.zeros((rows, states), dtype=np.int64)
        self.advice: AdviceRules | None = None  # None: no advice (transfer.exchange=advice sets it)
        self.advice_left = np.zeros(rows, dtype=np.int64)  # each agent's remaining advised steps
        self.fallbacks: list[list[_Fallback]] = [[] for _ in range(rows)]
        # Per replica: the counters of its draws, by purpose (what a checkpoint saves of them); per row the
        # key of each purpose's stream.
        self.counters = {stream: np.zeros(replicas, dtype=np.int64) for stream in _STREAM_NAMES}
        self.stream_keys = {
            stream: stream_keys(self.row_seed, number, self.row_agent) for stream, number in _STREAM_NAMES.items()
        }
        self.epsilon = np.zeros(rows)  # per agent, from the last act: transferred agents may explore less
        # SARSA: the action chosen at the last update for the next state, and that state's id.
        self.next_action = np.full(rows, _NO_ACTION, dtype=np.int64)
        self.next_state = np.full(rows, -1, dtype=np.int64)

    def replica(self, r: int) -> Team:
        return team_view(self, r)

    def _rows(self, replica: int | None) -> np.ndarray:
        """The rows of ``replica`` (None: all)."""
        k = self.num_agents
        return np.arange(self.num_rows) if replica is None else np.arange(replica * k, (replica + 1) * k)

    # ---------------------------------------------------------------------------------- tables

    def state_ids(self, obs: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The id of each row's observation ``obs [N, D]`` in its replica's index (``rows [N]``, may
        repeat). With the met-order index, new observations get the next ids, their entries starting at
        the fallbacks' values (else 0), and the arrays grow to hold them."""
        rows = np.asarray(rows, dtype=np.int64)
        ids, new_replicas, new_states = self.index.lookup(obs, rows)
        if self.index.capacity > self.q.shape[1]:
            self._grow(self.index.capacity)
        for r in np.unique(new_replicas).tolist():
            states = new_states[new_replicas == r]
            for row in self._rows(r).tolist():
                self.q[row, states] = self._start_values(row, self.index.observations(r, states))
        return ids

    def _grow(self, states: int) -> None:
        """Room for ``states`` states in every row (the new ones at 0, in no table, unvisited)."""
        more = states - self.q.shape[1]
        self.q = np.concatenate([self.q, np.zeros((self.num_rows, more, self.num_actions), np.float32)], axis=1)
        self.entry_order = np.concatenate([self.entry_order, np.full((self.num_rows, more), -1, np.int32)], axis=1)
        self.visits = np.concatenate([self.visits, np.zeros((self.num_rows, more), np.int64)], axis=1)

    def _start_values(self, row: int, obs: np.ndarray) -> np.ndarray:
        """What the entries of ``row`` for observations ``obs [N, D]`` hold before its agent updates
        them: for each, the values of the first fallback that knows it, else 0."""
        values = np.zeros((len(obs), self.num_actions), dtype=np.float32)
        open_ = np.ones(len(obs), dtype=bool)  # no fallback has known it yet
        for fallback in self.fallbacks[row]:
            found = fallback.rows_of(obs)
            fill = open_ & (found >= 0)
            values[fill] = fallback.values[found[fill]]
            open_ &= ~fill
        return values

    def q_values(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """Each agent's Q-values of its own observation: ``obs [rows, D] -> [rows, A]``."""
        return self.q_values_of(obs, self._rows(replica))

    def q_values_of(self, obs: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Row ``rows[n]``'s Q-values of ``obs[n]`` (rows may repeat)."""
        states = self.state_ids(obs, rows)  # before reading self.q: new states may grow it
        return self.q[rows, states]

    def agent_q_values(self, i: int, obs: np.ndarray) -> np.ndarray:
        """Agent (row) i's Q-values of one observation (a copy)."""
        state = self.state_ids(np.asarray(obs)[None], np.array([i]))[0]  # before reading self.q (may grow)
        return self.q[i, state].copy()

    def add_fallback(
        self, keys: np.ndarray, values: np.ndarray, projection: np.ndarray, agent: int | None = None
    ) -> None:
        """Start unseen entries from a table keyed on ``obs[projection]`` (all agents by default),
        looked up after the fallbacks added before it.

        ``keys [N, Ds]`` float32, ``values [N, A]`` float32, ``projection [Ds]``: the indices of the
        observation columns that form a key. Observations no table knows stay at 0.
        """
        keys, values, projection = np.asarray(keys), np.asarray(values), np.asarray(projection)
        check_fallback(keys, values, projection, self.obs_dim, self.num_actions)
        for row in range(self.num_rows) if agent is None else [agent]:
            self.fallbacks[row].append(_Fallback(keys, values, projection))
            self._restart_entries(row)

    def _restart_entries(self, row: int) -> None:
        """Set the entries of ``row`` that its agent has not updated to their start values (with dense
        tables: of every state of the game, from their observations decoded at once)."""
        r = int(self.row_replica[row])
        states = np.flatnonzero(self.entry_order[row, : self.index.count(r)] < 0)
        self.q[row, states] = self._start_values(row, self.index.observations(r, states))

    def _enter(self, rows: np.ndarray, states: np.ndarray) -> None:
        """Count ``(rows[n], states[n])`` as in their agents' tables, in this order, if not yet."""
        new = self.entry_order[rows, states] < 0
        if new.any():
            # One running number across all rows keeps each row's entries in the order they came.
            count = int(new.sum())
            self.entry_order[rows[new], states[new]] = self.num_entries + np.arange(count)
            self.num_entries += count

    # ---------------------------------------------------------------------------------- acting

    def _draws(self, stream: str, rows: np.ndarray) -> np.ndarray:
        """``[len(rows), 3]`` uniforms of ``stream`` at each row's replica's current counter."""
        counters = self.counters[stream][self.row_replica[rows]]
        return uniforms(self.stream_keys[stream][rows], counters, DRAWS_PER_AGENT_STEP)

    def _advance(self, stream: str, replica: int | None) -> None:
        if replica is None:
            self.counters[stream] += 1
        else:
            self.counters[stream][replica] += 1

    def act(
        self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray, replica: int | None = None
    ) -> np.ndarray:
        """Epsilon-greedy per live agent; SARSA replays the action its last update chose for ``obs``
        (advised or not, as decided then). With advice, an agent may play a team-mate's greedy action
        instead (:meth:`start_advice`). Non-live agents get action 0 (every agent takes its draws, live
        or not)."""
        rows = self._rows(replica)
        live = np.asarray(live, dtype=bool)
        self.epsilon[rows] = epsilon
        states = self.state_ids(obs, rows)
        actions = epsilon_greedy_rows(self.q[rows, states], self.epsilon[rows], self._draws("act", rows))
        cached = live & (self.next_action[rows] != _NO_ACTION) & (self.next_state[rows] == states)
        actions = np.where(cached, self.next_action[rows], actions)
        actions = self._advise(rows, states, actions, asking=live & ~cached)
        self.next_action[rows[live]] = _NO_ACTION
        self._advance("act", replica)
        return np.where(live, actions, 0).astype(np.int64)

    def best_actions(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """Each agent's actions of the highest value: every action of a state whose entry is still all
        0. Uses no cached action and no random numbers, so evaluating does not change the training run;
        :meth:`greedy` breaks the ties with the evaluation episode's generator, so that agents whose
        values are equal play the same moves whatever their observations encode."""
        q = self.q_values(obs, replica)
        return q == q.max(axis=1, keepdims=True)

    def best_actions_stacked(self, obs: np.ndarray) -> np.ndarray:
        """:meth:`best_actions` of E observations per row (``obs [E, rows, D]``, every replica's rows),
        all looked up at once."""
        episodes = len(obs)
        rows = np.tile(self._rows(None), episodes)
        q = self.q_values_of(obs.reshape(episodes * self.num_rows, -1), rows)
        return (q == q.max(axis=1, keepdims=True)).reshape(episodes, self.num_rows, -1)

    # -------------------------------------------------------------------------------- learning

    def update(self, transition: Transition, step: int) -> UpdateStats:
        """One table update per live agent. ``q_mean`` is ``Q(s, a)`` before the update, ``td_loss``
        the Huber loss of the TD error. ``step`` is unused (tabular learning has no schedule)."""
        td_loss = np.full(self.num_rows, np.nan)
        q_mean = np.full(self.num_rows, np.nan)
        live = np.flatnonzero(transition.live)
        draws = self._draws("next_action", live)
        self._advance("next_action", None)
        if live.size:
            q_mean[live], td_loss[live] = self._learn(
                live,
                transition.obs[live],
                np.asarray(transition.actions)[live],
                np.asarray(transition.rewards, dtype=np.float32)[live],
                transition.next_obs[live],
                np.asarray(transition.terminated, dtype=bool)[live],
                cache=~np.asarray(transition.truncated, dtype=bool)[live],
                draws=draws,
            )
        return UpdateStats(td_loss, q_mean)

    def _learn(
        self,
        rows: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        cache: np.ndarray,
        draws: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One update of each of ``rows`` (distinct) on its transition; returns ``Q(s, a)`` before it
        and the Huber loss of the TD error. The transitions are the agents' own: each counts as a visit.
        SARSA draws ``a'`` from ``draws`` and, where ``cache`` and the transition does not terminate,
        keeps it for the agent's next :meth:`act`: that is where advice replaces it, so the update
        bootstraps on the action the agent then plays."""
        states, next_states = self.state_ids(obs, rows), self.state_ids(next_obs, rows)
        self.visits[rows, states] += 1  # after the lookups, which may grow the arrays
        self.next_action[rows] = _NO_ACTION
        if self.algorithm == Algorithm.qlearning.value:
            next_action = np.full(len(rows), -1, dtype=np.int64)  # bootstrap on the max
        else:
            keep = cache & ~terminated
            chosen = epsilon_greedy_rows(self.q[rows, next_states], self.epsilon[rows], draws)
            next_action = self._advise(rows, next_states, chosen, asking=keep)
            self.next_action[rows[keep]] = next_action[keep]
            self.next_state[rows[keep]] = next_states[keep]
        q_sa, td_error = update_rows(
            self.q,
            rows,
            states,
            np.asarray(actions, dtype=np.int64),
            rewards,
            next_states,
            terminated,
            next_action,
            np.float32(self.gamma),
            np.float32(self.lr),
        )
        self._enter(rows, states)
        return q_sa, huber(td_error.astype(np.float64))  # DQN's loss, so td_loss curves compare

    # -------------------------------------------------------------------------- knowledge exchange

    def soft_copy_best(self, best: int, tau: float, replica: int = 0) -> None:
        """Q_i(s) <- (1 - tau) Q_i(s) + tau Q_best(s) for every other agent i of the replica, on every
        state either table holds (a state one of them never updated counts at its start value: its
        fallback's, or 0)."""
        rows = self._rows(replica)
        best_row = int(rows[best])
        count = self.index.count(replica)
        best_order = self.entry_order[best_row, :count]
        for row in rows.tolist():
            if row == best_row:
                continue
            held = (self.entry_order[row, :count] >= 0) | (best_order >= 0)
            mixed = (1 - tau) * self.q[row, :count] + tau * self.q[best_row, :count]
            self.q[row, :count] = np.where(held[:, None], mixed.astype(np.float32), self.q[row, :count])
            new = np.flatnonzero((self.entry_order[row, :count] < 0) & (best_order >= 0))
            new = new[np.argsort(best_order[new], kind="stable")]  # in the best agent's order
            self._enter(np.full(len(new), row), new)

    def learn_from(self, i: int, experience: Experience) -> None:
        """A table has no replay: one update of agent i per transition, in order, as if it had been its
        own (SARSA draws the next action from its own epsilon-greedy policy, from its learn-from stream).
        One that does not terminate bootstraps like any non-terminal step but caches no next action: the
        cache belongs to the agent's own next step (each update clears it, as its own updates do).

        :meth:`_learn` once per transition, in one compiled loop: the ids, draws and entry order are
        found for all transitions at once (none depends on the values), then the values are updated one
        after another, each update reading the ones before (tests check it against :meth:`_learn`)."""
        count = len(experience.obs)
        if count == 0:
            return
        replica = int(self.row_replica[i])
        # The ids in the order one-at-a-time updates meet them (s then s' of each), so new states get theirs.
        met = np.stack([np.asarray(experience.obs), np.asarray(experience.next_obs)], axis=1).reshape(2 * count, -1)
        ids = self.state_ids(met, np.full(2 * count, i)).reshape(count, 2)
        counters = self.counters["learn_from"][replica] + np.arange(count)
        draws = uniforms(np.full(count, self.stream_keys["learn_from"][i]), counters, DRAWS_PER_AGENT_STEP)
        self.counters["learn_from"][replica] += count
        self.next_action[i] = _NO_ACTION
        update_in_order(
            self.q,
            i,
            np.ascontiguousarray(ids[:, 0]),
            np.asarray(experience.actions, dtype=np.int64),
            np.asarray(experience.rewards, dtype=np.float32),
            np.ascontiguousarray(ids[:, 1]),
            np.asarray(experience.terminated, dtype=bool),
            draws,
            float(self.epsilon[i]),
            self.algorithm == Algorithm.sarsa.value,
            np.float32(self.gamma),
            np.float32(self.lr),
        )
        first = np.sort(np.unique(ids[:, 0], return_index=True)[1])  # each state where first updated
        self._enter(np.full(len(first), i), ids[first, 0])

    def merge_confident(self, weight: float, replica: int = 0) -> None:
        """Confidence-weighted merge inside the replica (:func:`~dqn_transfer.agents.visit_exchange.confident_merge`).
        A merged entry new to an agent enters its table grouped by the team-mate it came from (the lowest
        index first), each group in that team-mate's order: an order a resumed run rebuilds exactly."""
        rows = self._rows(replica)
        count = self.index.count(replica)
        values, merged, source = confident_merge(self.q[rows, :count], self.visits[rows, :count], weight)
        self.q[rows, :count] = values
        for agent, row in enumerate(rows.tolist()):
            new = np.flatnonzero(merged[agent] & (self.entry_order[row, :count] < 0))
            mates = source[agent, new]
            new = new[np.lexsort((self.entry_order[rows[mates], new], mates))]
            self._enter(np.full(len(new), row), new)

    def start_advice(self, rules: AdviceRules, replica: int | None = None) -> None:
        """Advise the exploring actions by ``rules`` from now on; the replica's (None: every) agents get
        the full budget."""
        self.advice = rules
        self.advice_left[self._rows(replica)] = rules.budget

    def _advise(self, rows: np.ndarray, states: np.ndarray, actions: np.ndarray, asking: np.ndarray) -> np.ndarray:
        """``actions`` of ``rows`` in ``states``, where ``asking`` and advice is given (by :attr:`advice`,
        within each agent's budget, which it spends) the advisor's greedy action. No random numbers."""
        if self.advice is None or not asking.any():
            return actions
        team = (rows - self.row_agent[rows])[:, None] + np.arange(self.num_agents)  # [N, K] each row's team
        advised, advice = advised_actions(
            self.visits[team, states[:, None]], self.row_agent[rows], self.q[team, states[:, None]], self.advice
        )
        advised &= asking & (self.advice_left[rows] > 0)
        self.advice_left[rows[advised]] -= 1
        return np.where(advised, advice, actions)

    # ----------------------------------------------------------------------------- checkpoints

    def agent_tensors(self, i: int) -> dict[str, np.ndarray]:
        """``keys [N, D]`` / ``values [N, A]`` float32 of the entries agent i has updated, in the order
        it first did, plus the fallbacks in lookup order (``fallback_keys``, ``fallback_values``,
        ``fallback_projection`` int64, then ``fallback1_*``...)."""
        r = int(self.row_replica[i])
        order = self.entry_order[i, : self.index.count(r)]
        states = np.flatnonzero(order >= 0)
        states = states[np.argsort(order[states], kind="stable")]
        tensors = {"keys": self.index.observations(r, states).copy(), "values": self.q[i, states].copy()}
        for level, fallback in enumerate(self.fallbacks[i]):
            arrays: tuple[np.ndarray, ...] = (fallback.keys, fallback.values, fallback.projection)
            for name, array in zip(fallback_names(level), arrays):
                tensors[name] = array.copy()
        return tensors

    def load_agent_tensors(self, i: int, tensors: dict[str, np.ndarray]) -> None:
        """Replace agent i's table and fallbacks (none if the tensors have none)."""
        keys = np.asarray(tensors["keys"], dtype=np.float32)
        check_tensor_shape("keys", keys, (keys.shape[0], self.obs_dim))
        check_tensor_shape("values", tensors["values"], (keys.shape[0], self.num_actions))
        values = np.asarray(tensors["values"], dtype=np.float32)
        tables = fallback_tables(tensors)
        for table in tables:  # checked before anything changes
            check_fallback(*table, self.obs_dim, self.num_actions)
        self.fallbacks[i] = []
        self.entry_order[i] = -1
        self.visits[i] = 0  # a loaded table brings no visits of this run (a resume state brings them back)
        for table in tables:
            self.fallbacks[i].append(_Fallback(*table))
        self._restart_entries(i)
        rows = np.full(len(keys), i)
        states = self.state_ids(keys, rows)
        self.q[i, states] = values
        self._enter(rows, states)

    def network_meta(self) -> dict[str, Any]:
        return {"obs_dim": self.obs_dim, "num_actions": self.num_actions}

    def training_state(self, replica: int = 0) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """One replica's SARSA next-action cache, draw counters, visit counts (by observation, sorted: the
        states' ids are not kept) and advice budgets (the tables are in ``agent_tensors``)."""
        rows = self._rows(replica)
        cached = self.next_action[rows] != _NO_ACTION
        next_obs = np.zeros((len(rows), self.obs_dim), dtype=np.float32)
        next_obs[cached] = self.index.observations(replica, self.next_state[rows[cached]])
        visited = np.flatnonzero(self.visits[rows, : self.index.count(replica)].any(axis=0))
        # In the observations' lexicographic order: ids depend on the order of lookups (an evaluation
        # picture looks up states early; a resume enters them anew) or on the game's code, the checkpoint
        # must not.
        keys = self.index.observations(replica, visited)
        order = np.lexsort(keys.T[::-1])
        visited = visited[order]
        arrays = {
            "next_action": self.next_action[rows].copy(),
            "next_action_obs": next_obs,
            "visit_keys": keys[order],
            "visits": self.visits[rows[:, None], visited],
            "advice_left": self.advice_left[rows].copy(),
        }
        counters = {stream: int(counts[replica]) for stream, counts in self.counters.items()}
        return arrays, {"draw_counters": counters, "epsilon": self.epsilon[rows].tolist()}

    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], replica: int = 0) -> None:
        if "draw_counters" not in meta:
            raise ValueError(
                "this tabular checkpoint was written before the tabular learners drew counter-based random "
                "numbers (2026-12-02): its run cannot continue exactly; start it again, or warm-start from "
                "its agent files (transfer.source=...)"
            )
        rows = self._rows(replica)
        next_action = np.asarray(arrays["next_action"], dtype=np.int64)
        cached = next_action != _NO_ACTION
        next_state = np.full(len(rows), -1, dtype=np.int64)
        next_state[cached] = self.state_ids(np.asarray(arrays["next_action_obs"])[cached], rows[cached])
        self.next_action[rows], self.next_state[rows] = next_action, next_state
        self.visits[rows] = 0
        if "visits" in arrays:  # a checkpoint from before visits were counted: none
            keys = np.asarray(arrays["visit_keys"])
            states = self.state_ids(keys, np.full(len(keys), rows[0]))  # before indexing: may grow
            self.visits[rows[:, None], states] = arrays["visits"]
            self.advice_left[rows] = arrays["advice_left"]
        for stream, count in meta["draw_counters"].items():
            self.counters[stream][replica] = int(count)
        self.epsilon[rows] = np.broadcast_to(np.asarray(meta["epsilon"], dtype=float), (self.num_agents,))


# The counter-based streams by name (as checkpoints save their counters) and number (in the draws' key).
_STREAM_NAMES = {"act": ACT_STREAM, "next_action": NEXT_ACTION_STREAM, "learn_from": LEARN_FROM_STREAM}
