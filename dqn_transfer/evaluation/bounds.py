"""Scripted reference teams drawn beside the learners, on the same maps and evaluation episodes.

See docs/bounds.md. There are three:

* :data:`~dqn_transfer.enums.Bound.oracle`, the upper reference: it sees the whole game (every agent's
  cell, the true chests) and, at every step, matches the live agents to the full chests for the least
  total shortest-path length (:func:`~dqn_transfer.envs.rules.best_assignment`, the deliberative
  coordinator's rule and tie-break); each agent takes one step along a shortest path to its chest.
* :data:`~dqn_transfer.enums.Bound.greedy`, the floor: each agent, from its own observation alone,
  takes one step towards the nearest chest it believes full (or, when its observation carries a
  deliberative ``assignment``, towards that chest), with no coordination.
* :data:`~dqn_transfer.enums.Bound.random`, the zero of a normalised score: each live agent takes an
  action drawn uniformly at every step, from a generator of its own.

All are :data:`~dqn_transfer.evaluation.rollout.Policy` callables played by :func:`play_episode`
through the game's own ``step``, so a bound's record is :func:`summarize`'s, key for key.

Paths are the BFS shortest paths of :meth:`~dqn_transfer.envs.maps.GridMap.distances_from`, around
obstacles and traps: an agent never walks into either while it has a chest to go to. A chest that no
trap-free path reaches (impossible on a map that passed ``parse_layout``, whose rule 3 forbids it) is
out of reach: the agent does not cross a trap for it, and stays instead. Of several shortest paths,
an agent takes the first action in the order up, down, left, right. An agent without a chest stays:
the game has no "stay" action, so it moves off the grid if it can (which leaves it in place), else onto
a free cell or a chest believed empty, else into an obstacle (back to its start) or a full chest, and
into a trap only if nothing else is left.

    python -m dqn_transfer.cli.bounds --map-seed 0 --size 8 --num-treasures 4 --num-traps 4 \\
        --num-agents 4 --mode cooperative --episodes 5
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dqn_transfer.compiled import kernel
from dqn_transfer.enums import Bound
from dqn_transfer.envs import Game, rules, tie_draws
from dqn_transfer.envs.game import TreasureHuntGame, TreasureHunts
from dqn_transfer.envs.maps import GridMap
from dqn_transfer.envs.rules import ACTION_MOVES, best_assignment
from dqn_transfer.evaluation.rollout import Policy, evaluation_rng, play_episode, summarize

# How an agent without a chest ranks a move (lowest first): staying in place, a harmless cell, a move
# that ends its wait anyway (an obstacle sends it to its start, a full chest ends it with the treasure),
# a trap.
_STAYS, _HARMLESS, _DISPLACES, _TRAPPED = range(4)


class Walker:
    """Moves on one map: a step along a shortest trap-free path to a chest, or staying put.

    Cells are flat indices ``row * n + col``, as in the game's ``position`` segment.
    """

    def __init__(self, grid_map: GridMap) -> None:
        n = grid_map.size
        cells = n * n
        # [k, cells] BFS steps from each cell to each chest around obstacles and traps; -1: no such path.
        self.distances = np.stack([grid_map.distances_from(chest).reshape(-1) for chest in grid_map.chests])
        rows, cols = np.divmod(np.arange(cells), n)
        self.neighbours = np.empty((cells, len(ACTION_MOVES)), dtype=np.int64)  # a move off the grid stays
        for action, (dr, dc) in enumerate(ACTION_MOVES):
            r, c = rows + dr, cols + dc
            inside = (r >= 0) & (r < n) & (c >= 0) & (c < n)
            self.neighbours[:, action] = np.where(inside, r * n + c, np.arange(cells))
        self.obstacle = np.isin(np.arange(cells), [r * n + c for r, c in grid_map.obstacles])
        self.trap = np.isin(np.arange(cells), [r * n + c for r, c in grid_map.traps])
        self.chest_at = np.full(cells, -1, dtype=np.int64)
        self.chest_at[[r * n + c for r, c in grid_map.chests]] = np.arange(grid_map.num_treasures)

    def toward(self, cell: int, chest: int) -> int | None:
        """The first action one step nearer ``chest``; ``None`` when no trap-free path reaches it."""
        distance = self.distances[chest]
        if distance[cell] < 0:
            return None
        return next(a for a in range(len(ACTION_MOVES)) if distance[self.neighbours[cell, a]] == distance[cell] - 1)

    def stay(self, cell: int, full: np.ndarray) -> int:
        """The action that best keeps an agent where it is, ``full`` the chests it believes full."""
        return min(range(len(ACTION_MOVES)), key=lambda action: self._stay_rank(cell, action, full))

    def _stay_rank(self, cell: int, action: int, full: np.ndarray) -> int:
        to = self.neighbours[cell, action]
        if to == cell:
            return _STAYS
        if self.trap[to]:
            return _TRAPPED
        if self.obstacle[to] or (self.chest_at[to] >= 0 and full[self.chest_at[to]]):
            return _DISPLACES
        return _HARMLESS

    def act(self, cell: int, chest: int, full: np.ndarray) -> int:
        """A step towards ``chest`` (``-1``: none), else staying put."""
        move = self.toward(cell, chest) if chest >= 0 else None
        return self.stay(cell, full) if move is None else move

    def nearest(self, cell: int, full: np.ndarray) -> int:
        """The nearest reachable chest of those ``full`` marks (the lower number on equal distance), ``-1``: none."""
        distance = self.distances[:, cell]
        candidates = np.flatnonzero(full & (distance >= 0))
        return int(candidates[np.argmin(distance[candidates])]) if candidates.size else -1

    def matching(self, cells: np.ndarray, live: np.ndarray, full: np.ndarray) -> np.ndarray:
        """Each agent's chest (``-1``: none) in a minimum-total-distance matching of the ``live`` agents at
        ``cells`` to the ``full`` chests, with the coordinator's tie-break."""
        agents, chests = np.flatnonzero(live), np.flatnonzero(full)
        targets = np.full(len(cells), -1, dtype=np.int64)
        if agents.size and chests.size:
            distance = self.distances[np.ix_(chests, cells[agents])].T
            # Worse than any matching of reachable pairs (as in the game's coordinator), so as many agents as
            # possible get a chest they can reach; one matched out of reach stays (Walker.toward: None).
            unreachable = len(cells) * self.distances.shape[1]
            picks = best_assignment(np.where(distance < 0, unreachable, distance).astype(np.int64))
            targets[agents] = np.where(picks >= 0, chests[picks], -1)
        return targets


def oracle_policy(game: TreasureHuntGame) -> Policy:
    """The oracle team of ``game``: reads the game's true state, re-matches every step.

    Re-matching every step is consistent: each matched agent's step shortens the matching in hand by
    one, so the best total falls by the number of matched agents per step and the team walks exactly
    the minimum total distance, whichever optimal matching the tie-break picks. An emptied chest, or
    an agent that ended, simply leaves the next matching. A shortest path may cross another full
    chest; the agent then takes that one (and ends), which never costs the team a step (an exchange
    of the two agents' chests is at least as short).
    """
    walker = Walker(game.map)

    def act(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        rows, cols = game.positions.T
        cells = rows * game.size + cols
        full = game.chest_full
        targets = walker.matching(cells, live, full)
        actions = np.zeros(len(live), dtype=np.int64)  # a finished agent's action is ignored
        for agent in np.flatnonzero(live).tolist():
            actions[agent] = walker.act(int(cells[agent]), int(targets[agent]), full)
        return actions

    return act


def greedy_policy(game: TreasureHuntGame) -> Policy:
    """The greedy team of ``game``: each agent from its own observation row alone (its cell, the chests
    it believes full, and in deliberative mode the coordinator's ``assignment``, followed when it names
    a chest; one without a chest there goes to its nearest chest believed full)."""
    walker = Walker(game.map)
    offsets = game.obs_offsets()
    position, treasures = (slice(*offsets[name]) for name in ("position", "treasures"))
    assignment = slice(*offsets.get("assignment", (0, 0)))  # empty outside deliberative mode
    codes = game.position_codes()  # the agent's cell is the one whose code its `position` segment holds

    def act(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        cells = np.abs(obs[:, None, position] - codes[None]).sum(axis=2).argmin(axis=1)
        believed_full = obs[:, treasures] > 0.5
        # A finished agent's action is ignored (and a deliberative one still shows the chest it ended on).
        actions = np.zeros(len(live), dtype=np.int64)
        for agent in np.flatnonzero(live).tolist():
            cell = int(cells[agent])
            assigned = obs[agent, assignment]  # one-hot, or all 0: no chest assigned
            chest = int(assigned.argmax()) if assigned.any() else walker.nearest(cell, believed_full[agent])
            actions[agent] = walker.act(cell, chest, believed_full[agent])
        return actions

    return act


def random_policy(game: Game, rng: np.random.Generator) -> Policy:
    """The uniformly random team of ``game`` (any game): every agent draws its action from ``rng`` at every
    step (a finished agent's draw is ignored)."""

    def act(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        return rng.integers(game.num_actions, size=len(live))

    return act


POLICIES = {Bound.oracle: oracle_policy, Bound.greedy: greedy_policy}
RANDOM_TEAM_STREAM = 1_000_033  # the random team's actions: apart from the episodes' tie draws


def evaluate_bound(game: Game, kind: Bound | str, episodes: int, seed: int) -> dict[str, Any]:
    """``episodes`` episodes of the ``kind`` team, as :func:`summarize` records a learner's evaluation; the
    oracle and the greedy team play the treasure hunt, the random team any game.

    Episode ``e`` resets with ``evaluation_rng(seed, 0, e)``: the generator of episode ``e`` of a run of
    ``seed``'s evaluation at step 0, which draws only the winners of chest ties. The random team draws its
    actions from one generator of its own, ``default_rng([seed, RANDOM_TEAM_STREAM])``, over the episodes in
    order.
    """
    kind = Bound(kind)
    if kind is Bound.random:
        policy = random_policy(game, np.random.default_rng([seed, RANDOM_TEAM_STREAM]))
    elif isinstance(game, TreasureHuntGame):  # it keeps nothing between steps, so one serves every episode
        policy = POLICIES[kind](game)
    else:
        raise ValueError(f"the {kind.value} team walks a treasure hunt's map; {game.factory} has none")
    rngs = (evaluation_rng(seed, 0, episode) for episode in range(episodes))
    return summarize([play_episode(game, policy, rng) for rng in rngs])


def random_team_return(game: Game, episodes: int, seed: int) -> float:
    """The random team's mean team return: ``evaluate_bound(game, "random", episodes, seed)["team_return"]``,
    the same float, played by a compiled kernel on a treasure hunt (:func:`play_drawn`, ~100x faster).

    The episodes' actions can be drawn before they are played: the generator draws ``integers`` from one
    stream, so a step's K draws in turn are the next K of one long draw."""
    if not isinstance(game, TreasureHuntGame):
        return float(evaluate_bound(game, Bound.random, episodes, seed)["team_return"])
    hunt = TreasureHunts([game.map], **game.settings())
    longest = episodes * hunt.max_steps * hunt.num_agents  # every step of every episode draws K actions
    actions = np.random.default_rng([seed, RANDOM_TEAM_STREAM]).integers(hunt.num_actions, size=longest)
    tie_rngs = np.zeros((episodes, tie_draws.WORDS), dtype=np.uint64)
    for episode in range(episodes):
        tie_draws.pack(evaluation_rng(seed, 0, episode), tie_rngs[episode])
    returns = np.zeros(episodes)
    play_drawn(actions, tie_rngs, returns, *hunt.rule_constants, *hunt.kernel_arrays())
    return float(np.mean(returns))


@kernel
def play_drawn(actions, tie_rngs, returns, rewards, max_steps, team, announce, *row):
    """Episode ``e`` of replica 0 of a :func:`~dqn_transfer.envs.rules.arrays` row, for each episode in
    turn: reset with the packed tie generator ``tie_rngs[e]``, played to its end with its agents' actions
    read from ``actions`` in order, from where the episode before stopped; its team return (as
    :class:`~dqn_transfer.evaluation.rollout.EpisodeTally` sums it) into ``returns[e]``."""
    tables = rules.Tables(*row[: rules.TABLES_END])
    state = rules.State(*row[rules.TABLES_END : rules.STATE_END])
    out = rules.Outcome(*row[rules.STATE_END :])
    agents = state.pos.shape[1]
    start = 0
    for episode in range(len(returns)):
        state.tie_rng[0] = tie_rngs[episode]
        rules.reset_replica(tables, state, 0)
        total = 0.0
        while state.live[0].any():
            step_actions = actions[start : start + agents].reshape(1, agents)
            rules.step(tables, state, step_actions, out, rewards, max_steps, team, announce)
            total += rules.team_step_return(out, 0, team)
            start += agents
        returns[episode] = total
