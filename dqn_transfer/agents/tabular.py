"""Tabular SARSA (the study's base learner) and Q-learning for K agents.

Each agent has its own Q-table keyed by the exact observation (the bytes of its float32 vector).
An unseen observation is worth 0 for every action, unless the agent has *fallbacks*: tables from
another agent (set by transfer), each looked up on a projection of the observation, in turn; the
first that knows it initialises the entry the first time it is updated.

Update of agent i for a transition ``(s, a, r, s')``, learning rate ``alpha = lr``::

    y = r                                  if s' is terminal
    y = r + gamma * Q(s', a')              SARSA: a' epsilon-greedy on Q(s', .), played next
    y = r + gamma * max_a' Q(s', a')       Q-learning
    Q(s, a) <- Q(s, a) + alpha * (y - Q(s, a))

A truncated episode (time limit) bootstraps like any non-terminal step. SARSA picks ``a'`` at
update time with the epsilon of the last ``act``, and the next ``act`` on ``s'`` returns that same
action, so the update follows the policy actually played (on-policy).
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
    epsilon_greedy_action,
)
from dqn_transfer.agents.replicas import team_view
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm

_NO_ACTION = -1  # empty slot of the SARSA next-action cache


def huber(td_error: float) -> float:
    """The DQN loss of a TD error (smooth L1), so tabular and deep ``td_loss`` curves compare."""
    magnitude = abs(td_error)
    return 0.5 * magnitude**2 if magnitude < 1.0 else magnitude - 0.5


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


def _best_actions(q: np.ndarray) -> list[int]:
    """The actions of the highest value (in Python: for a handful of actions, cheaper than numpy calls)."""
    values = q.tolist()
    top = max(values)
    return [action for action, value in enumerate(values) if value == top]


class TabularLearner(Learner, KnowledgeExchange):
    """K independent Q-tables updated by SARSA or Q-learning (see the module docstring), in R replicas:
    ``R * K`` tables, row ``r * K + k``, replica r exploring and breaking ties with its own generator
    (exactly the team a lone learner of its seed would be)."""

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
        self.num_replicas = len(seeds)
        self.num_rows = rows = self.num_replicas * num_agents
        self.rngs = [np.random.default_rng(s) for s in seeds]
        self.tables: list[dict[bytes, np.ndarray]] = [{} for _ in range(rows)]
        self.fallbacks: list[list[_Fallback]] = [[] for _ in range(rows)]
        # SARSA: the action chosen for next_obs at the last update, and that observation.
        self.epsilon = np.zeros(rows)  # per agent: transferred agents may explore less
        self.next_action = np.full(rows, _NO_ACTION, dtype=np.int64)
        self.next_action_obs = np.zeros((rows, self.obs_dim), dtype=np.float32)

    def replica(self, r: int) -> Team:
        return team_view(self, r)

    def _rows(self, replica: int | None) -> range:
        """The rows of ``replica`` (None: all)."""
        k = self.num_agents
        return range(self.num_rows) if replica is None else range(replica * k, (replica + 1) * k)

    def _rng(self, i: int) -> np.random.Generator:
        return self.rngs[i // self.num_agents]

    # ---------------------------------------------------------------------------------- tables

    def q_values(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """Each agent's Q-values of its own observation: ``obs [rows, D] -> [rows, A]``."""
        obs = np.asarray(obs, dtype=np.float32)
        return np.stack([self.agent_q_values(i, obs[n]) for n, i in enumerate(self._rows(replica))])

    def agent_q_values(self, i: int, obs: np.ndarray) -> np.ndarray:
        """Agent i's Q-values of one observation, without adding an entry (do not modify)."""
        row = self.tables[i].get(obs.tobytes())
        for fallback in self.fallbacks[i]:
            if row is not None:
                break
            row = fallback.get(obs)
        return row if row is not None else np.zeros(self.num_actions, dtype=np.float32)

    def _entry(self, i: int, obs: np.ndarray) -> np.ndarray:
        """Agent i's table row for ``obs``, created (from the fallback, else zeros) when unseen."""
        key = obs.tobytes()
        if key not in self.tables[i]:
            self.tables[i][key] = self.agent_q_values(i, obs).copy()
        return self.tables[i][key]

    def _greedy(self, q: np.ndarray, rng: np.random.Generator) -> int:
        """Argmax with random tie-breaking: a fresh table is all ties, and always taking the
        first action would bias early exploration towards it."""
        best = _best_actions(q)
        return best[0] if len(best) == 1 else int(rng.choice(best))

    def _epsilon_greedy(self, i: int, q: np.ndarray) -> int:
        rng = self._rng(i)
        return epsilon_greedy_action(self._greedy(q, rng), self.epsilon[i], self.num_actions, rng)

    def add_fallback(
        self, keys: np.ndarray, values: np.ndarray, projection: np.ndarray, agent: int | None = None
    ) -> None:
        """Initialise unseen entries from a table keyed on ``obs[projection]`` (all agents by default),
        looked up after the fallbacks added before it.

        ``keys [N, Ds]`` float32, ``values [N, A]`` float32, ``projection [Ds]``: the indices of the
        observation columns that form a key. Observations no table knows stay at 0.
        """
        keys, values, projection = np.asarray(keys), np.asarray(values), np.asarray(projection)
        well_formed = keys.ndim == 2 and projection.shape == (keys.shape[1],)
        if not well_formed or values.shape != (len(keys), self.num_actions):
            raise ValueError(
                f"fallback table is malformed: keys {list(keys.shape)}, values {list(values.shape)}, "
                f"projection {list(projection.shape)}, {self.num_actions} actions"
            )
        if projection.size and (projection.min() < 0 or projection.max() >= self.obs_dim):
            raise ValueError(f"fallback projection points outside the {self.obs_dim} observation columns")
        agents = range(self.num_rows) if agent is None else [agent]
        for i in agents:
            self.fallbacks[i].append(_Fallback(keys, values, projection))

    # ---------------------------------------------------------------------------------- acting

    def act(
        self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray, replica: int | None = None
    ) -> np.ndarray:
        """Epsilon-greedy per live agent; SARSA replays the action its last update chose for ``obs``.
        Non-live agents get action 0 and draw no random numbers."""
        obs = np.asarray(obs, dtype=np.float32)
        rows = self._rows(replica)
        actions = np.zeros(len(rows), dtype=np.int64)
        self.epsilon[rows.start : rows.stop] = epsilon
        for n in np.flatnonzero(live).tolist():
            i = rows.start + n
            if self._cached(i, obs[n]):
                actions[n] = self.next_action[i]
                self.next_action[i] = _NO_ACTION
            else:
                actions[n] = self._epsilon_greedy(i, self.agent_q_values(i, obs[n]))
        return actions

    def best_actions(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """Each agent's actions of the highest value: every action of a state its table and fallbacks
        do not know (all 0). Uses no cached action and no random numbers, so evaluating does not change
        the training run; :meth:`greedy` breaks the ties with the evaluation episode's generator, so that
        agents whose values are equal play the same moves whatever their observations encode."""
        obs = np.asarray(obs, dtype=np.float32)
        rows = self._rows(replica)
        best = np.zeros((len(rows), self.num_actions), dtype=bool)
        for n, i in enumerate(rows):
            best[n, _best_actions(self.agent_q_values(i, obs[n]))] = True
        return best

    def _cached(self, i: int, obs: np.ndarray) -> bool:
        """Whether agent i's last update chose its next action for exactly this observation."""
        return self.next_action[i] != _NO_ACTION and self.next_action_obs[i].tobytes() == obs.tobytes()

    # -------------------------------------------------------------------------------- learning

    def update(self, transition: Transition, step: int) -> UpdateStats:
        """One table update per live agent. ``q_mean`` is ``Q(s, a)`` before the update, ``td_loss``
        the Huber loss of the TD error. ``step`` is unused (tabular learning has no schedule)."""
        obs = np.asarray(transition.obs, dtype=np.float32)
        next_obs = np.asarray(transition.next_obs, dtype=np.float32)
        rewards = np.asarray(transition.rewards, dtype=np.float32)
        actions, terminated, truncated = transition.actions, transition.terminated, transition.truncated
        td_loss = np.full(self.num_rows, np.nan)
        q_mean = np.full(self.num_rows, np.nan)
        for i in np.flatnonzero(transition.live).tolist():
            q_mean[i], td_loss[i] = self._update_one(
                i, obs[i], int(actions[i]), rewards[i], next_obs[i], terminated[i], cache=not truncated[i]
            )
        return UpdateStats(td_loss, q_mean)

    def _update_one(
        self, i: int, obs: np.ndarray, a: int, reward: np.float32, next_obs: np.ndarray, terminated: bool, cache: bool
    ) -> tuple[np.float32, float]:
        """Agent i's table update on one transition; returns ``Q(s, a)`` before it and the Huber loss."""
        self.next_action[i] = _NO_ACTION
        row = self._entry(i, obs)
        target = reward
        if not terminated:
            bootstrap = self._bootstrap(i, next_obs, cache=cache)
            target = reward + np.float32(self.gamma) * bootstrap
        td_error = target - row[a]
        q_mean, td_loss = row[a], huber(float(td_error))
        row[a] += np.float32(self.lr) * td_error
        return q_mean, td_loss

    def _bootstrap(self, i: int, next_obs: np.ndarray, cache: bool) -> np.float32:
        """The value of ``next_obs`` the target uses: Q(s', a') for SARSA, max Q(s', .) for Q-learning.

        SARSA caches a' to be played next, unless the episode ends here (truncation): then the next
        act() starts a new episode and a' is used only in this target.
        """
        q_next = self.agent_q_values(i, next_obs)
        if self.algorithm == Algorithm.qlearning.value:
            return q_next.max()
        next_action = self._epsilon_greedy(i, q_next)
        if cache:
            self.next_action[i] = next_action
            self.next_action_obs[i] = next_obs
        return q_next[next_action]

    # -------------------------------------------------------------------------- knowledge exchange

    def soft_copy_best(self, best: int, tau: float, replica: int = 0) -> None:
        """Q_i(s) <- (1 - tau) Q_i(s) + tau Q_best(s) for every other agent i of the replica, on every
        state either table holds (a state one of them never saw counts at the value it would look up:
        its fallback's, or 0)."""
        rows = self._rows(replica)
        best = rows.start + best
        best_table = self.tables[best]
        for i in rows:
            if i == best:
                continue
            for key in list(dict.fromkeys([*self.tables[i], *best_table])):
                obs = np.frombuffer(key, dtype=np.float32)
                self.tables[i][key] = (
                    (1 - tau) * self.agent_q_values(i, obs) + tau * self.agent_q_values(best, obs)
                ).astype(np.float32)

    def learn_from(self, i: int, experience: Experience) -> None:
        """A table has no replay: one update of agent i per transition, as if it had been its own (SARSA
        draws the next action from its own epsilon-greedy policy). One that does not terminate
        bootstraps like any non-terminal step but caches no next action: the cache belongs to the
        agent's own next step (each update clears it, as its own updates do)."""
        obs = np.asarray(experience.obs, dtype=np.float32)
        next_obs = np.asarray(experience.next_obs, dtype=np.float32)
        rewards = np.asarray(experience.rewards, dtype=np.float32)
        for o, a, r, o2, done in zip(obs, experience.actions, rewards, next_obs, experience.terminated):
            self._update_one(i, o, int(a), r, o2, done, cache=False)

    # ----------------------------------------------------------------------------- checkpoints

    def agent_tensors(self, i: int) -> dict[str, np.ndarray]:
        """``keys [N, D]`` / ``values [N, A]`` float32 in insertion order, plus the fallbacks in lookup
        order (``fallback_keys``, ``fallback_values``, ``fallback_projection`` int64, then ``fallback1_*``...)."""
        table = self.tables[i]
        keys = np.zeros((len(table), self.obs_dim), dtype=np.float32)
        values = np.zeros((len(table), self.num_actions), dtype=np.float32)
        for n, (key, row) in enumerate(table.items()):
            keys[n] = np.frombuffer(key, dtype=np.float32)
            values[n] = row
        tensors = {"keys": keys, "values": values}
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
        self.tables[i] = {key.tobytes(): row.copy() for key, row in zip(keys, values)}
        self.fallbacks[i] = []
        for table in fallback_tables(tensors):
            self.add_fallback(*table, agent=i)

    def network_meta(self) -> dict[str, Any]:
        return {"obs_dim": self.obs_dim, "num_actions": self.num_actions}

    def training_state(self, replica: int = 0) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """One replica's SARSA next-action cache and RNG state (the tables are in ``agent_tensors``)."""
        rows = slice(self._rows(replica).start, self._rows(replica).stop)
        arrays = {"next_action": self.next_action[rows].copy(), "next_action_obs": self.next_action_obs[rows].copy()}
        return arrays, {"rng": self.rngs[replica].bit_generator.state, "epsilon": self.epsilon[rows].tolist()}

    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], replica: int = 0) -> None:
        rows = slice(self._rows(replica).start, self._rows(replica).stop)
        self.next_action[rows] = np.asarray(arrays["next_action"], dtype=np.int64)
        self.next_action_obs[rows] = np.asarray(arrays["next_action_obs"], dtype=np.float32)
        self.rngs[replica].bit_generator.state = meta["rng"]
        self.epsilon[rows] = np.broadcast_to(np.asarray(meta["epsilon"], dtype=float), (self.num_agents,))
