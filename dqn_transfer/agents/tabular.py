"""Tabular SARSA (the study's base learner) and Q-learning for K agents, in R replicas, as arrays.

Each agent has its own Q-table over the exact observations (float32 vectors) of its game. The
observations a replica's agents meet get dense ids in the order they are first seen (one index per
replica: its agents share the game), so every agent's table is a row of one array ``Q [R * K, S, A]``
and acting or updating all agents of all replicas is a few array operations. An observation is worth
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

import math
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
from dqn_transfer.agents.random_streams import mix64, stream_keys, uniforms
from dqn_transfer.agents.replicas import team_view
from dqn_transfer.agents.visit_exchange import AdviceRules, VisitExchange, advised_actions, confident_merge
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm

_NO_ACTION = -1  # empty slot of the SARSA next-action cache


def observation_hashes(bits: np.ndarray, replicas: np.ndarray) -> np.ndarray:
    """``uint64 [N]``: a hash of each row's (replica, observation bits ``[N, D]`` uint32) pair. Each
    value is mixed with its column first, so the sum over columns tells reordered values apart."""
    columns = np.arange(bits.shape[1], dtype=np.uint64) << np.uint64(32)
    with np.errstate(over="ignore"):  # uint64 arithmetic wraps by design
        values = mix64(bits.astype(np.uint64) | columns).sum(axis=1, dtype=np.uint64)
        return mix64(values + mix64(np.asarray(replicas).astype(np.uint64)))


# The purposes of the counter-based draws (one stream each).
ACT_STREAM, NEXT_ACTION_STREAM, LEARN_FROM_STREAM = 1, 2, 3
DRAWS_PER_AGENT_STEP = 3  # explore?, a random action, a pick among tied best actions
_INITIAL_STATES = 64  # ids a replica's index holds before it first grows (doubling)


def epsilon_greedy_rows(q: np.ndarray, epsilon: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Per row of ``q [N, A]``: with probability ``epsilon [N]`` a uniformly random action, else a best
    action, ties going to a uniformly drawn one of them; ``draws [N, 3]`` uniforms in ``[0, 1)`` (one
    per choice, always all three)."""
    best = q == q.max(axis=1, keepdims=True)
    pick = np.floor(draws[:, 2] * best.sum(axis=1)).astype(np.int64)  # the pick-th best action
    greedy = np.argmax(np.cumsum(best, axis=1) > pick[:, None], axis=1)
    random_action = np.floor(draws[:, 1] * q.shape[1]).astype(np.int64)
    return np.where(draws[:, 0] < epsilon, random_action, greedy)


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
        self.table = {key.tobytes(): row for key, row in zip(self.keys, self.values)}

    def get(self, obs: np.ndarray) -> np.ndarray | None:
        return self.table.get(obs[self.projection].tobytes())


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
    ) -> None:
        """
        :param num_agents: K, the agents of the team (one table each)
        :param obs_layout: the observation's named segments ``[(name, size), ...]``
        :param num_actions: A, the discrete actions
        :param hp: the hyperparameters, documented on :class:`~dqn_transfer.config.AgentConfig`:
            ``algorithm`` (sarsa | qlearning), ``lr`` (alpha, the step size of the table update), ``gamma``
        :param seed: fixes exploration and tie-breaking; a list of R seeds makes R replicas
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
        # Each replica's observations by id (its agents share the index), and how many it has.
        self._ids: list[dict[bytes, int]] = [{} for _ in range(replicas)]
        # In front of the dicts, for lookups of all rows at once: the known (replica, observation) pairs'
        # hashes, sorted, and their ids. A hit is checked against the stored observation, so a hash
        # collision only sends that observation to its dict.
        self._hashes = np.zeros(0, dtype=np.uint64)
        self._hashed_ids = np.zeros(0, dtype=np.int64)
        self._new_hashes: list[tuple[int, int]] = []  # (hash, id) of the states added in this lookup
        self.state_keys = np.zeros((replicas, _INITIAL_STATES, self.obs_dim), dtype=np.float32)
        self.num_states = np.zeros(replicas, dtype=np.int64)
        self._last_obs = np.zeros((rows, self.obs_dim), dtype=np.uint32)  # each row's last observation's bits
        self._last_ids = np.full(rows, -1, dtype=np.int64)  # ... and its id (-1: none yet)
        self.q = np.zeros((rows, _INITIAL_STATES, num_actions), dtype=np.float32)
        # Entry order: when the agent first updated it (-1: not in its table, the value is a start value).
        self.entry_order = np.full((rows, _INITIAL_STATES), -1, dtype=np.int32)
        self._entries = 0  # entries entered so far, all rows together (the next entry's order)
        # Visits: how many of its own transitions each agent has learned from in each state (what the
        # exchanges by visit counts weigh, agents/visit_exchange.py); team-mates' transitions do not count.
        self.visits = np.zeros((rows, _INITIAL_STATES), dtype=np.int64)
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
        """The id of each row's observation ``obs [N, D]`` in its replica's index (``rows [N]``),
        new observations getting the next ids (their entries start at the fallbacks' values, else 0).

        A row's last observation and id are remembered: the loop asks for the same observation again
        (act on s', then update on it), so only the rows whose observation changed are looked up."""
        obs = np.ascontiguousarray(obs, dtype=np.float32)
        rows = np.asarray(rows, dtype=np.int64)
        bits = obs.view(np.uint32)  # compared bit for bit, as the index's keys are
        same = (self._last_ids[rows] >= 0) & (bits == self._last_obs[rows]).all(axis=1)
        ids = self._last_ids[rows]
        changed = np.flatnonzero(~same)
        if changed.size:
            replicas = self.row_replica[rows[changed]]
            hashes = observation_hashes(bits[changed], replicas)
            found = self._known_ids(hashes, replicas, bits[changed])
            for n in np.flatnonzero(found < 0).tolist():  # unseen, or a hash collision: the dict decides
                r, key = int(replicas[n]), obs[changed[n]].tobytes()
                known = self._ids[r].get(key)
                found[n] = self._new_state(r, key, obs[changed[n]], int(hashes[n])) if known is None else known
            self._index_new_hashes()
            ids[changed] = found
            # Remember each row's last looked-up observation (a row may come more than once).
            last = len(changed) - 1 - np.unique(rows[changed][::-1], return_index=True)[1]
            self._last_obs[rows[changed[last]]] = bits[changed[last]]
            self._last_ids[rows[changed[last]]] = found[last]
        return ids

    def _known_ids(self, hashes: np.ndarray, replicas: np.ndarray, bits: np.ndarray) -> np.ndarray:
        """The ids the hash index gives (``-1``: no hit, or a hit on another observation)."""
        at = np.minimum(np.searchsorted(self._hashes, hashes), max(len(self._hashes) - 1, 0))
        hit = np.flatnonzero(self._hashes[at] == hashes) if len(self._hashes) else np.zeros(0, dtype=np.int64)
        found = np.full(len(hashes), -1, dtype=np.int64)
        candidates = self._hashed_ids[at[hit]]
        stored = self.state_keys[replicas[hit], candidates].view(np.uint32)
        found[hit] = np.where((stored == bits[hit]).all(axis=1), candidates, -1)
        return found

    def _new_state(self, r: int, key: bytes, obs: np.ndarray, hashed: int) -> int:
        state = int(self.num_states[r])
        if state == self.q.shape[1]:
            self._grow()
        self._ids[r][key] = state
        self._new_hashes.append((hashed, state))
        self.state_keys[r, state] = obs
        self.num_states[r] += 1
        for row in self._rows(r).tolist():
            self.q[row, state] = self._start_values(row, obs)
        return state

    def _index_new_hashes(self) -> None:
        """Add the states of this lookup to the hash index, one insertion for all. A hash already
        there (a collision) keeps its first state; the other observation is found in its dict."""
        if not self._new_hashes:
            return
        hashes = np.array([hashed for hashed, _ in self._new_hashes], dtype=np.uint64)
        states = np.array([state for _, state in self._new_hashes], dtype=np.int64)
        self._new_hashes.clear()
        hashes, first = np.unique(hashes, return_index=True)
        at = np.searchsorted(self._hashes, hashes)
        fresh = self._hashes[np.minimum(at, len(self._hashes) - 1)] != hashes if len(self._hashes) else at >= 0
        self._hashes = np.insert(self._hashes, at[fresh], hashes[fresh])
        self._hashed_ids = np.insert(self._hashed_ids, at[fresh], states[first][fresh])

    def _grow(self) -> None:
        """Double every replica's room for states."""
        self.q = np.concatenate([self.q, np.zeros_like(self.q)], axis=1)
        self.entry_order = np.concatenate([self.entry_order, np.full_like(self.entry_order, -1)], axis=1)
        self.visits = np.concatenate([self.visits, np.zeros_like(self.visits)], axis=1)
        self.state_keys = np.concatenate([self.state_keys, np.zeros_like(self.state_keys)], axis=1)

    def _start_values(self, row: int, obs: np.ndarray) -> np.ndarray:
        """What an entry of ``row`` holds before its agent updates it: the first fallback that knows
        ``obs``, else 0."""
        for fallback in self.fallbacks[row]:
            values = fallback.get(obs)
            if values is not None:
                return values
        return np.zeros(self.num_actions, dtype=np.float32)

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
        """Set the entries of ``row`` that its agent has not updated to their start values."""
        r = int(self.row_replica[row])
        for state in np.flatnonzero(self.entry_order[row, : self.num_states[r]] < 0).tolist():
            self.q[row, state] = self._start_values(row, self.state_keys[r, state])

    def _enter(self, rows: np.ndarray, states: np.ndarray) -> None:
        """Count ``(rows[n], states[n])`` as in their agents' tables, in this order, if not yet."""
        new = self.entry_order[rows, states] < 0
        if new.any():
            # One running number across all rows keeps each row's entries in the order they came.
            count = int(new.sum())
            self.entry_order[rows[new], states[new]] = self._entries + np.arange(count)
            self._entries += count

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
        q_next = self.q[rows, next_states]
        if self.algorithm == Algorithm.qlearning.value:
            bootstrap = q_next.max(axis=1)
        else:
            keep = cache & ~terminated
            next_action = self._advise(
                rows, next_states, epsilon_greedy_rows(q_next, self.epsilon[rows], draws), asking=keep
            )
            bootstrap = q_next[np.arange(len(rows)), next_action]
            self.next_action[rows[keep]] = next_action[keep]
            self.next_state[rows[keep]] = next_states[keep]
        q_sa = self.q[rows, states, actions]
        target = np.where(terminated, rewards, rewards + np.float32(self.gamma) * bootstrap).astype(np.float32)
        td_error = target - q_sa
        self.q[rows, states, actions] = q_sa + np.float32(self.lr) * td_error
        self._enter(rows, states)
        return q_sa, huber(td_error.astype(np.float64))  # DQN's loss, so td_loss curves compare

    # -------------------------------------------------------------------------- knowledge exchange

    def soft_copy_best(self, best: int, tau: float, replica: int = 0) -> None:
        """Q_i(s) <- (1 - tau) Q_i(s) + tau Q_best(s) for every other agent i of the replica, on every
        state either table holds (a state one of them never updated counts at its start value: its
        fallback's, or 0)."""
        rows = self._rows(replica)
        best_row = int(rows[best])
        count = int(self.num_states[replica])
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

        :meth:`_learn` once per transition, computed with scalars: the ids, draws and entry order
        are found for all transitions at once (none depends on the values), then the values are updated
        one after another, each update reading the ones before (tests check it against :meth:`_learn`)."""
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
        q = self.q[i]  # a view: the updates below land in the table
        num_actions = self.num_actions
        gamma, lr, epsilon = np.float32(self.gamma), np.float32(self.lr), float(self.epsilon[i])
        sarsa = self.algorithm == Algorithm.sarsa.value
        rewards = np.asarray(experience.rewards, dtype=np.float32)
        terminated = np.asarray(experience.terminated, dtype=bool).tolist()
        actions = np.asarray(experience.actions).tolist()
        for n, ((state, next_state), draw) in enumerate(zip(ids.tolist(), draws.tolist())):
            q_next = q[next_state]
            if sarsa:  # epsilon_greedy_rows for one row
                if draw[0] < epsilon:
                    next_action = math.floor(draw[1] * num_actions)
                else:
                    best = np.flatnonzero(q_next == q_next.max())
                    next_action = int(best[math.floor(draw[2] * len(best))])
                bootstrap = q_next[next_action]
            else:
                bootstrap = q_next.max()
            q_sa = q[state, actions[n]]
            target = rewards[n] if terminated[n] else rewards[n] + gamma * bootstrap
            q[state, actions[n]] = q_sa + lr * (target - q_sa)
        first = np.sort(np.unique(ids[:, 0], return_index=True)[1])  # each state where first updated
        self._enter(np.full(len(first), i), ids[first, 0])

    def merge_confident(self, weight: float, replica: int = 0) -> None:
        """Confidence-weighted merge inside the replica (:func:`~dqn_transfer.agents.visit_exchange.confident_merge`).
        A merged entry new to an agent enters its table grouped by the team-mate it came from (the lowest
        index first), each group in that team-mate's order: an order a resumed run rebuilds exactly."""
        rows = self._rows(replica)
        count = int(self.num_states[replica])
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
        order = self.entry_order[i, : self.num_states[r]]
        states = np.flatnonzero(order >= 0)
        states = states[np.argsort(order[states], kind="stable")]
        tensors = {"keys": self.state_keys[r, states].copy(), "values": self.q[i, states].copy()}
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
        next_obs[cached] = self.state_keys[replica, self.next_state[rows[cached]]]
        visited = np.flatnonzero(self.visits[rows, : self.num_states[replica]].any(axis=0))
        # In the observations' lexicographic order: ids depend on the order of lookups (an evaluation
        # picture looks up states early; a resume enters them anew), the checkpoint must not.
        keys = self.state_keys[replica, visited]
        visited = visited[np.lexsort(keys.T[::-1])]
        arrays = {
            "next_action": self.next_action[rows].copy(),
            "next_action_obs": next_obs,
            "visit_keys": self.state_keys[replica, visited].copy(),
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
