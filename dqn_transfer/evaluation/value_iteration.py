"""Exact optimal team returns of small one-chest maps, in every mode (docs/claim1_exact.md).

The study's claim 1 says that with one treasure, cooperation (the announcement of a taken chest) gives
no advantage over competition. This module settles it exactly on small maps with one chest and at most
two agents. The quantity is the **team return**: the undiscounted sum of every agent's rewards over one
episode of at most ``max_steps`` joint steps (the study's ``team_return``). For each mode it computes

* the **joint optimum** ``V*``: the best expected team return of any joint policy that sees the whole
  game (every agent's cell, who is live, whether the chest is full, the step count). It is finite-horizon
  value iteration on the **joint MDP**: the joint states ``(cells of the live agents, live flags, chest
  full)`` reachable from the start, every joint action, and the successor and team reward of each, all
  read off the game's own :meth:`~dqn_transfer.envs.game.TreasureHuntGame.step` (no copy of the rules).
  A chest tie is two successors of probability 1/2, the two winners the game can draw. The step count is
  the DP's time index: ``V_T = 0`` at the horizon ``T = max_steps`` (there the game truncates every
  agent still live), ``V_t(s) = max_a mean_draw [r(s, a) + V_{t+1}(s')]``;
* the **decentralised value**: the team return of a team in which each agent acts on its own
  observation row in that mode alone (the expanded state ``<s_agent, s_env>``, as the learners do:
  stationary, without memory or step count), built from ``V*`` and replayed through the real game
  (:func:`~dqn_transfer.evaluation.rollout.play_episode`). Such a team is one joint policy among
  others, so its value is at most ``V*``; when its replayed return *equals* ``V*``, ``V*`` is the exact
  optimum of every class of policies between the two (own observation, own observation history with a
  step count, full information), in that mode.

The team is found by walking the joint optimum forward through the game in that mode: at each step,
among the joint actions of optimal value, one whose every live agent's action agrees with what that
agent already did at the same observation (preferring one without a chest tie, then the lowest joint
action), so that each agent's actions form a table from its observations. ``None`` when no optimal
action agrees at some step (the walk does not backtrack): then only ``V*`` is known, as an upper bound.

Why one chest and at most two agents: an episode then has at most one tie, between two agents, so two
replays (a generator drawing winner 0, one drawing winner 1) give the expectation exactly.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from dqn_transfer.enums import Mode
from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.envs.maps import GridMap, parse_layout, resolve_map
from dqn_transfer.evaluation.rollout import Policy, play_episode, team_return_of

# (cell of each agent, -1 once done; live flags; chest full flags): what the dynamics depend on.
JointState = tuple[tuple[int, ...], tuple[bool, ...], tuple[bool, ...]]
DRAWS = 2  # the winners of a two-agent chest tie, each drawn with probability 1/2
# Seeds whose generator's first two-way draw is 0, resp. 1: the game draws a tie's winner as
# ``rng.integers(len(contenders))``, so a game reset or loaded with TIE_SEEDS[d] gives contender d the chest.
TIE_SEEDS = tuple(
    next(s for s in itertools.count() if np.random.default_rng(s).integers(DRAWS) == d) for d in range(DRAWS)
)

# Small hand-made maps with a trap and obstacles; their optima are worked out in docs/claim1_exact.md.
SMALL_LAYOUTS = {
    "4x4": "0..#\n.#..\n...T\nX.1.",
    "5x5": "0....\n.#.#.\n..T..\n.#...\nX...1",
}
# The maps of experiment=claim1 (conf/experiment/claim1.yaml: env=simple with 1 chest, 1 trap, 2 agents),
# map seeds 0..9 (its replicas.maps); tests/test_value_iteration.py checks these against the config files.
CLAIM1_MAP: dict[str, Any] = {"size": 6, "num_treasures": 1, "num_traps": 1, "num_agents": 2, "complexity": 0.1}
CLAIM1_SEEDS = range(10)
DEFAULT_MAPS = (*SMALL_LAYOUTS, *(f"claim1:{seed}" for seed in CLAIM1_SEEDS))


def tie_rng(draw: int) -> np.random.Generator:
    """A generator with which the game gives a two-agent chest tie to contender ``draw`` (0 or 1)."""
    return np.random.default_rng(TIE_SEEDS[draw])


def named_map(name: str) -> GridMap:
    """``4x4`` or ``5x5`` (:data:`SMALL_LAYOUTS`), or ``claim1:SEED``: the claim-1 map of that map seed."""
    if name in SMALL_LAYOUTS:
        return parse_layout(SMALL_LAYOUTS[name])
    prefix, _, seed = name.partition(":")
    if prefix != "claim1" or not seed.isdigit():
        raise ValueError(f"unknown map {name!r}: give {', '.join(SMALL_LAYOUTS)} or claim1:SEED (SEED an integer >= 0)")
    return resolve_map(**CLAIM1_MAP, map_seed=int(seed))


@dataclass(frozen=True)
class JointModel:
    """The joint MDP of a game as its own ``step`` plays it, over the joint states reachable from the start.

    ``states[0]`` is the start. ``successor[s, a, d]`` and ``reward[s, a, d]`` are the next state and the
    team reward of joint action ``actions[a]`` in state ``s`` when a chest tie goes to contender ``d``
    (the same for both ``d`` when the step has no tie). A state with no live agent is absorbing, reward 0.
    """

    states: tuple[JointState, ...]
    index: dict[JointState, int]
    actions: np.ndarray  # [A, K] every joint action
    successor: np.ndarray  # [S, A, DRAWS] int64
    reward: np.ndarray  # [S, A, DRAWS] float64

    def same_dynamics(self, other: JointModel) -> bool:
        """Whether ``other`` has the same states, successors and rewards (e.g. the game in another mode)."""
        return (
            self.states == other.states
            and np.array_equal(self.successor, other.successor)
            and np.array_equal(self.reward, other.reward)
        )

    def q_values(self, values: np.ndarray, t: int, state: int) -> np.ndarray:
        """``[A]`` expected team return of each joint action in ``state`` after ``t`` steps, then optimal play."""
        return (self.reward[state] + values[t + 1][self.successor[state]]).mean(axis=1)


def _check_small(game: TreasureHuntGame) -> None:
    """``ValueError`` unless the game has one chest and at most two agents (see the module docstring)."""
    if game.num_treasures != 1 or game.num_agents > DRAWS:
        raise ValueError(
            f"exact values need one chest and at most {DRAWS} agents; this map has "
            f"{game.num_treasures} chests and {game.num_agents} agents"
        )


def _state_of(game: TreasureHuntGame) -> JointState:
    rows, cols = game.positions.T
    live = game.live
    cells = np.where(live, rows * game.size + cols, -1)
    return tuple(cells.tolist()), tuple(live.tolist()), tuple(game.chest_full.tolist())


def _load(game: TreasureHuntGame, state: JointState, draw: int) -> None:
    """Put ``game`` in ``state`` at step 0 (a done agent on its start, beliefs the truth), ties to ``draw``.

    Only the dynamics are read from a game loaded so: its observations are not the episode's.
    """
    cells, live, full = state
    starts = [r * game.size + c for r, c in game.map.starts[: game.num_agents]]
    agents = game.num_agents
    game.load_state_dict(
        {
            "pos": [cell if alive else start for cell, alive, start in zip(cells, live, starts)],
            "live": list(live),
            "chest_full": list(full),
            "belief": [[float(f) for f in full]] * agents,
            "assigned": [-1] * agents,
            "obs": np.zeros((agents, game.obs_dim), dtype=np.float32),
            "t": 0,
            "treasures_collected": full.count(False),
        },
        tie_rng(draw),
    )


def _step_from(
    game: TreasureHuntGame, state: JointState, joint: np.ndarray, draw: int
) -> tuple[JointState, float, int]:
    """The game's successor of ``state`` under ``joint``, the step's team reward and the chests it emptied."""
    _load(game, state, draw)
    live = game.live
    outcome = game.step(joint)
    return _state_of(game), team_return_of(outcome.rewards, live, game.reward_mode), outcome.treasures_collected


def joint_model(game: TreasureHuntGame) -> JointModel:
    """The joint MDP of ``game`` (its map, rules and mode), by breadth-first search from the start through
    the game's own ``step``; the horizon is left to :func:`optimal_values`."""
    _check_small(game)
    # Every step is taken from step count 0, so any horizon above one step never truncates here.
    stepper = TreasureHuntGame(game.map, **{**game.settings(), "max_steps": 2})
    stepper.reset(tie_rng(0))
    actions = np.array(list(itertools.product(range(game.num_actions), repeat=game.num_agents)), dtype=np.int64)
    states = [_state_of(stepper)]
    index = {states[0]: 0}
    successors: list[list[list[int]]] = []
    rewards: list[list[list[float]]] = []
    for state in states:  # grows while it is walked: a breadth-first search
        rows_s, rows_r = [], []
        for joint in actions:
            if not any(state[1]):
                outcomes = [(state, 0.0)] * DRAWS
            else:
                first, reward, emptied = _step_from(stepper, state, joint, 0)
                # Only a step that empties a chest can draw a tie's winner (docs/game.md).
                second = _step_from(stepper, state, joint, 1)[:2] if emptied else (first, reward)
                outcomes = [(first, reward), second]
            for successor, _ in outcomes:
                if successor not in index:
                    index[successor] = len(states)
                    states.append(successor)
            rows_s.append([index[successor] for successor, _ in outcomes])
            rows_r.append([value for _, value in outcomes])
        successors.append(rows_s)
        rewards.append(rows_r)
    return JointModel(
        tuple(states), index, actions, np.array(successors, dtype=np.int64), np.array(rewards, dtype=np.float64)
    )


def optimal_values(model: JointModel, horizon: int) -> np.ndarray:
    """``[horizon + 1, S]``: ``values[t, s]`` is the best expected team return from state ``s`` after ``t``
    joint steps; ``values[horizon] = 0`` (the game truncates there)."""
    values = np.zeros((horizon + 1, len(model.states)))
    for t in range(horizon - 1, -1, -1):
        values[t] = (model.reward + values[t + 1][model.successor]).mean(axis=2).max(axis=1)
    return values


def stationary_team(game: TreasureHuntGame, model: JointModel, values: np.ndarray) -> list[dict[bytes, int]] | None:
    """Each agent's action per own observation row (its bytes), playing the joint optimum in ``game``'s
    mode; ``None`` when no optimal joint action fits the tables at some step (module docstring).

    ``game`` is not touched: the walk plays a replica of it, once with each tie winner.
    """
    play = game.replica()
    tables: list[dict[bytes, int]] = [{} for _ in range(game.num_agents)]
    for draw in range(DRAWS):
        obs = play.reset(tie_rng(draw))
        while not play.done:
            state = model.index[_state_of(play)]
            q = model.q_values(values, play.steps, state)
            best = q.max()
            live = np.flatnonzero(play.live).tolist()
            seen = [obs[agent].tobytes() for agent in range(play.num_agents)]
            fitting = [
                a
                for a in np.flatnonzero(q >= best - 1e-9 * max(1.0, abs(best))).tolist()
                if all(tables[i].get(seen[i], model.actions[a, i]) == model.actions[a, i] for i in live)
            ]
            if not fitting:
                return None
            tie = model.successor[state, :, 0] != model.successor[state, :, 1]
            choice = min(fitting, key=lambda a: (bool(tie[a]), a))
            for agent in live:
                tables[agent][seen[agent]] = int(model.actions[choice, agent])
            obs = play.step(model.actions[choice]).obs
    return tables


def table_policy(tables: list[dict[bytes, int]]) -> Policy:
    """The team of :func:`stationary_team`: each live agent looks its own observation row up in its table."""

    def act(obs: np.ndarray, live: np.ndarray) -> np.ndarray:
        actions = np.zeros(len(live), dtype=np.int64)  # a finished agent's action is ignored
        for agent in np.flatnonzero(live).tolist():
            actions[agent] = tables[agent][obs[agent].tobytes()]
        return actions

    return act


def expected_return(game: TreasureHuntGame, policy: Policy) -> float:
    """The expected team return of ``policy`` in ``game``: the mean of the episodes with each tie winner
    (with one chest an episode has at most one tie), played by the game's own episode loop."""
    return float(np.mean([play_episode(game, policy, tie_rng(draw)).team_return for draw in range(DRAWS)]))


class ModeValue(NamedTuple):
    """One mode's values on one map."""

    mode: Mode
    joint_optimum: float  # V*: full information, a joint policy
    decentralised: float | None  # the own-observation team's replayed return; None: none found (module docstring)
    model: JointModel


class MapValues(NamedTuple):
    """Every mode's values on one map."""

    name: str
    size: int
    horizon: int
    modes: tuple[ModeValue, ...]

    @property
    def same_dynamics(self) -> bool:
        """Whether every mode's joint MDP is the same (the modes then differ only in what agents observe)."""
        first = self.modes[0].model
        return all(first.same_dynamics(value.model) for value in self.modes[1:])

    def value(self, mode: Mode) -> ModeValue:
        return next(value for value in self.modes if value.mode is mode)


def mode_value(game: TreasureHuntGame) -> ModeValue:
    """The joint optimum and the decentralised value of ``game`` in its mode."""
    model = joint_model(game)
    values = optimal_values(model, game.max_steps)
    tables = stationary_team(game, model, values)
    decentralised = None if tables is None else expected_return(game, table_policy(tables))
    return ModeValue(game.mode, float(values[0, 0]), decentralised, model)


def map_values(name: str, grid_map: GridMap, max_steps: int | None = None) -> MapValues:
    """:func:`mode_value` in every mode on ``grid_map`` (default rules; ``max_steps`` ``None``: ``n * n``)."""
    games = [TreasureHuntGame(grid_map, mode=mode, max_steps=max_steps) for mode in Mode]
    return MapValues(name, grid_map.size, games[0].max_steps, tuple(mode_value(game) for game in games))


def _number(value: float | None) -> str:
    return "none found" if value is None else f"{value:g}"


def format_table(results: list[MapValues]) -> str:
    """A Markdown table: per map, the joint optimum, each mode's decentralised value, and cooperative minus
    competitive."""
    modes = list(Mode)
    lines = [
        "| map | n | horizon | joint states | same dynamics | V* (joint) | "
        + " | ".join(f"{mode.value} (own obs)" for mode in modes)
        + " | cooperative - competitive |",
        "|---|---:|---:|---:|---|---:|" + "---:|" * len(modes) + "---:|",
    ]
    for result in results:
        optima = sorted({value.joint_optimum for value in result.modes})
        competitive = result.value(Mode.competitive).decentralised
        cooperative = result.value(Mode.cooperative).decentralised
        gap = None if competitive is None or cooperative is None else cooperative - competitive
        cells = [
            result.name,
            str(result.size),
            str(result.horizon),
            str(len(result.modes[0].model.states)),
            "yes" if result.same_dynamics else "no",
            " / ".join(f"{v:g}" for v in optima),
            *(_number(result.value(mode).decentralised) for mode in modes),
            _number(gap),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
