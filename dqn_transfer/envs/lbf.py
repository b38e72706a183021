"""Level-Based Foraging (the ``lbforaging`` package) as a PettingZoo ParallelEnv with named observation
segments: the factory of ``env=lbf`` (docs/your_own_environment.md).

lbforaging's ``ForagingEnv`` is a Gymnasium env with tuple spaces (one entry per player); this adapter
gives it PettingZoo's parallel API (agents ``player_0`` ..) and two changes of meaning:

* the episode's time limit is a **truncation** (lbforaging reports it as ``done``), so learners
  bootstrap past it;
* a reset is a function of its seed alone: lbforaging's own places the new players away from the cells
  the last episode's players ended on, so the same seed gave another start after another episode (and
  a mid-episode checkpoint's replay could miss); the adapter clears those positions first;
* every player's observation is declared as segments, in lbforaging's order: ``food_0`` ..
  ``food_{F-1}`` (row, col, level of each food seen, ``(-1, -1, 0)`` when not seen), ``self`` (row,
  col, level) and ``player_1`` .. ``player_{P-1}`` (the other players seen). Transfer maps segments by
  name, so a source trained with fewer food items or players starts a larger task with its segments'
  weights and the new entries at zero weight: it computes the source's Q-values on every state the
  source could see (docs/transfer.md).

Two of lbforaging's methods run again here, faster, with the same results (``tests/test_lbf.py`` plays
them side by side with the originals): the observation vectors, written by a compiled kernel instead of
through named tuples and a space check of every vector, and each player's valid actions, read from the
field as a list (under a profiler the two took 37% of an LBF run's time). And a run's replicas step together:
:class:`ForagingBatch` plays lbforaging's step rules for all of them in one kernel call
(:func:`step_foraging`), where each step went through the adapters and lbforaging's Python for each replica;
their resets stay lbforaging's own (``tests/test_lbf.py`` plays the batch beside the games stepped one by one).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from lbforaging.foraging.environment import Action, ForagingEnv
from pettingzoo import ParallelEnv

from dqn_transfer.compiled import kernel
from dqn_transfer.envs.batch import BatchStep
from dqn_transfer.envs.game_batch import LoopedGames
from dqn_transfer.envs.pettingzoo_game import PettingZooGame

ENTRY = 3  # (row, col, level) of one food item or player
NONE, NORTH, SOUTH, WEST, EAST, LOAD = (action.value for action in Action)  # lbforaging's actions, in its order


def lbf_segments(food: int, players: int) -> list[tuple[str, int]]:
    """The named segments of an LBF observation with ``food`` items and ``players`` players.

    :param food: the most food items on the field.
    :param players: the players.
    """
    return (
        [(f"food_{i}", ENTRY) for i in range(food)]
        + [("self", ENTRY)]
        + [(f"player_{i}", ENTRY) for i in range(1, players)]
    )


@kernel
def write_observations(
    field: np.ndarray, positions: np.ndarray, levels: np.ndarray, sight: int, observe_levels: bool, out: np.ndarray
) -> None:
    """Every player's observation vector into ``out [players, width]``, as lbforaging's ``_make_gym_obs``
    writes it: the food in the player's window (the field within ``sight`` of it, clipped at the edges) in
    row-major order as (row, col, level) from the window's corner, ``(-1, -1, 0)`` for the rest; then the
    player itself and the others it sees, in their order, with positions from the same corner. lbforaging
    sees a player when both of its coordinates from that corner are within ``0..2 * sight``, which past the
    field's edge reaches beyond the food window: kept as it is.
    """
    rows, cols = field.shape
    players = positions.shape[0]
    entry = ENTRY if observe_levels else ENTRY - 1  # a player's (row, col[, level])
    food = (out.shape[1] - players * entry) // ENTRY
    for p in range(players):
        obs = out[p]
        row, col = positions[p, 0], positions[p, 1]
        top, left = max(row - sight, 0), max(col - sight, 0)
        for i in range(food):
            obs[3 * i], obs[3 * i + 1], obs[3 * i + 2] = -1.0, -1.0, 0.0
        seen = 0
        for y in range(top, min(row + sight + 1, rows)):
            for x in range(left, min(col + sight + 1, cols)):
                if field[y, x] != 0:
                    obs[3 * seen], obs[3 * seen + 1], obs[3 * seen + 2] = y - top, x - left, field[y, x]
                    seen += 1
        start = 3 * food
        for i in range(players):
            obs[start + entry * i], obs[start + entry * i + 1] = -1.0, -1.0
            if observe_levels:
                obs[start + entry * i + 2] = 0.0
        slot = 0
        for order in range(players):  # the player itself first, then the others in their order
            other = p if order == 0 else order - 1 + (order - 1 >= p)
            y, x = positions[other, 0] - top, positions[other, 1] - left
            if min(y, x) >= 0 and max(y, x) <= 2 * sight:
                obs[start + entry * slot], obs[start + entry * slot + 1] = y, x
                if observe_levels:
                    obs[start + entry * slot + 2] = levels[other]
                slot += 1


@kernel
def step_foraging(
    field: np.ndarray,
    positions: np.ndarray,
    levels: np.ndarray,
    actions: np.ndarray,
    steps: np.ndarray,
    food_spawned: np.ndarray,
    max_steps: int,
    penalty: float,
    normalize_reward: bool,
    sight: int,
    observe_levels: bool,
    rewards: np.ndarray,
    done: np.ndarray,
    food_left: np.ndarray,
    obs: np.ndarray,
) -> None:
    """One step of R LBF games with ``actions [R, P]``, as lbforaging's ``ForagingEnv.step`` plays it: an
    action the player cannot take is NONE; players move unless another player heads for the same cell; each
    group of loading players next to a food item loads it if their levels add up to its level (each scoring
    its level times the food's, over the group's level times the food spawned) or takes ``penalty`` each;
    the episode ends with no food left or at ``max_steps``. Changes ``field [R, rows, cols]``, ``positions [R,
    P, 2]`` and ``steps [R]`` in place; writes ``rewards [R, P]``, ``done [R]``, ``food_left [R]`` and every
    player's observation ``obs [R, P, width]`` (:func:`write_observations`).

    lbforaging takes the loading players in a set's order; here in theirs. No two food items are ever next to
    one cell (food spawns two cells apart at least), so each loading player has one food item in reach and
    the groups do not depend on the order."""
    replicas, players = actions.shape
    rows, cols = field.shape[1], field.shape[2]
    targets = np.empty((players, 2), dtype=np.int64)
    loading = np.zeros(players, dtype=np.bool_)
    for r in range(replicas):
        grid, where = field[r], positions[r]
        steps[r] += 1
        for p in range(players):
            row, col, action = where[p, 0], where[p, 1], actions[r, p]
            dy, dx = (action == SOUTH) - (action == NORTH), (action == EAST) - (action == WEST)
            if dy != 0 or dx != 0:  # a move onto the field's free cells only (players do not block it)
                if not (0 <= row + dy < rows and 0 <= col + dx < cols and grid[row + dy, col + dx] == 0):
                    action, dy, dx = NONE, 0, 0
            elif action == LOAD:  # lbforaging's adjacent_food: the four neighbours clamped to the field
                near = grid[max(row - 1, 0), col] + grid[min(row + 1, rows - 1), col]
                if near + grid[row, max(col - 1, 0)] + grid[row, min(col + 1, cols - 1)] == 0:
                    action = NONE
            targets[p, 0], targets[p, 1] = row + dy, col + dx
            loading[p] = action == LOAD
            rewards[r, p] = 0.0
        for p in range(players):  # a player moves unless another one heads for the same cell
            alone = True
            for q in range(players):
                if q != p and targets[q, 0] == targets[p, 0] and targets[q, 1] == targets[p, 1]:
                    alone = False
            if alone:
                where[p, 0], where[p, 1] = targets[p, 0], targets[p, 1]
        for p in range(players):
            if not loading[p]:
                continue
            row, col = where[p, 0], where[p, 1]
            # lbforaging's adjacent_food_location, its bounds as they are (row > 1, col > 1)
            if row > 1 and grid[row - 1, col] > 0:
                food_row, food_col = row - 1, col
            elif row < rows - 1 and grid[row + 1, col] > 0:
                food_row, food_col = row + 1, col
            elif col > 1 and grid[row, col - 1] > 0:
                food_row, food_col = row, col - 1
            elif col < cols - 1 and grid[row, col + 1] > 0:
                food_row, food_col = row, col + 1
            else:
                raise RuntimeError("a loading player has no food in reach")
            group = np.zeros(players, dtype=np.bool_)  # the loading players next to the food item
            group_level = 0
            for q in range(players):
                dy, dx = abs(where[q, 0] - food_row), abs(where[q, 1] - food_col)
                if loading[q] and ((dy == 1 and dx == 0) or (dx == 1 and dy == 0)):
                    group[q] = True
                    group_level += levels[r, q]
            food = grid[food_row, food_col]
            for q in range(players):
                if group[q]:
                    loading[q] = False
                    if group_level < food:
                        rewards[r, q] -= penalty
                    elif normalize_reward:
                        rewards[r, q] = float(levels[r, q] * food) / float(group_level * food_spawned[r])
                    else:
                        rewards[r, q] = float(levels[r, q] * food)
            if group_level >= food:
                grid[food_row, food_col] = 0
        food_left[r] = grid.sum() > 0
        done[r] = not food_left[r] or max_steps <= steps[r]
        write_observations(grid, where, levels[r], sight, observe_levels, obs[r])


class FastForagingEnv(ForagingEnv):
    """lbforaging's ``ForagingEnv`` with its vector observations and valid actions computed faster, to the
    same values (its grid observations are lbforaging's own)."""

    def _make_gym_obs(self) -> tuple[np.ndarray, ...]:
        if self._grid_observation:
            return super()._make_gym_obs()
        positions = np.array([player.position for player in self.players], dtype=np.int64)
        levels = np.array([player.level for player in self.players], dtype=np.int64)
        out = np.empty((len(self.players), *self.observation_space[0].shape), dtype=np.float32)
        write_observations(self.field, positions, levels, self.sight, self._observe_agent_levels, out)
        return tuple(out)

    def _gen_valid_moves(self) -> None:
        field = self.field.tolist()
        last_row, last_col = len(field) - 1, len(field[0]) - 1
        self._valid_actions = {}
        for player in self.players:
            row, col = player.position
            valid = [Action.NONE]
            if row > 0 and field[row - 1][col] == 0:
                valid.append(Action.NORTH)
            if row < last_row and field[row + 1][col] == 0:
                valid.append(Action.SOUTH)
            if col > 0 and field[row][col - 1] == 0:
                valid.append(Action.WEST)
            if col < last_col and field[row][col + 1] == 0:
                valid.append(Action.EAST)
            # lbforaging's adjacent_food: the four neighbours clamped to the field (so at an edge the
            # player's own cell, which holds no food)
            adjacent = (
                field[max(row - 1, 0)][col]
                + field[min(row + 1, last_row)][col]
                + field[row][max(col - 1, 0)]
                + field[row][min(col + 1, last_col)]
            )
            if adjacent > 0:
                valid.append(Action.LOAD)
            self._valid_actions[player] = valid


class LevelBasedForaging(ParallelEnv):
    """lbforaging's ``ForagingEnv`` behind PettingZoo's parallel API.

    :param size: the field's side.
    :param players: the players (agents).
    :param food: the most food items on the field.
    :param max_player_level: players' levels are drawn in 1..this each episode.
    :param min_food_level: the lowest food level.
    :param max_food_level: the highest food level; None: the sum of the three lowest players' levels.
    :param force_coop: every food needs all players to load it together (cooperative food).
    :param sight: how far a player sees; None: the whole field.
    :param max_steps: the time limit (a truncation).
    :param penalty: the reward of a failed load.
    :param render_mode: None or rgb_array.
    """

    metadata = {"name": "lbf_v0", "render_modes": ["rgb_array"]}

    def __init__(
        self,
        size: int = 8,
        players: int = 2,
        food: int = 2,
        max_player_level: int = 2,
        min_food_level: int = 1,
        max_food_level: int | None = None,
        force_coop: bool = False,
        sight: int | None = None,
        max_steps: int = 50,
        penalty: float = 0.0,
        render_mode: str | None = None,
    ) -> None:
        self.game = FastForagingEnv(
            players=players,
            min_player_level=1,
            max_player_level=max_player_level,
            min_food_level=min_food_level,
            max_food_level=max_food_level,
            field_size=(size, size),
            max_num_food=food,
            sight=size if sight is None else sight,
            max_episode_steps=max_steps,
            force_coop=force_coop,
            penalty=penalty,
            render_mode=render_mode,
        )
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.possible_agents = [f"player_{i}" for i in range(players)]
        self.agents: list[str] = []
        self.observation_segments = lbf_segments(food, players)

    def observation_space(self, agent: str) -> Any:
        return self.game.observation_space[self.possible_agents.index(agent)]

    def action_space(self, agent: str) -> Any:
        return self.game.action_space[self.possible_agents.index(agent)]

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        for player in self.game.players:
            player.position = None  # lbforaging places players away from the last episode's: forget them
        observations, _ = self.game.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        return dict(zip(self.agents, observations)), {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        joint = [int(actions.get(agent, 0)) for agent in self.possible_agents]  # 0: lbforaging's NONE
        observations, rewards, done, _, _ = self.game.step(joint)
        food_left = bool(np.any(self.game.field))
        time_up = done and food_left  # lbforaging ends the episode at the time limit with food left
        agents = self.agents
        self.agents = [] if done else list(self.possible_agents)
        return (
            dict(zip(agents, observations)),
            {agent: float(r) for agent, r in zip(agents, rewards)},
            {agent: done and not time_up for agent in agents},
            {agent: time_up for agent in agents},
            {agent: {} for agent in agents},
        )

    @staticmethod
    def batch_games(games: Sequence[PettingZooGame], rngs: Sequence[np.random.Generator]) -> ForagingBatch | None:
        """The replicas' games as one :class:`ForagingBatch`, or None where they cannot be: another env
        among them, other kwargs, or a game that draws."""
        first = games[0]
        if any(not isinstance(game.env, LevelBasedForaging) or game.kwargs != first.kwargs for game in games):
            return None
        return None if first.kwargs.get("render_mode") is not None else ForagingBatch(games, rngs)

    def render(self) -> Any:
        return self.game.render(mode="rgb_array") if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.game.close()


class ForagingBatch(LoopedGames):
    """R LBF games (:class:`~dqn_transfer.envs.pettingzoo_game.PettingZooGame` s of :class:`LevelBasedForaging`
    with one set of kwargs) stepped together by :func:`step_foraging`: the same steps as
    :class:`~dqn_transfer.envs.game_batch.LoopedGames` takes through lbforaging's own, to the bit
    (``tests/test_lbf.py``). A reset goes through the replica's own game (lbforaging's reset), a fixed instance's
    only once: its start is kept. A checkpoint's episode is replayed there too, and saved in the one-game format.

    :param games: one game per replica, each at the start of (or inside) the episode to continue
    :param rngs: each replica's generator, given to the game at every reset
    """

    def __init__(self, games: Sequence[PettingZooGame], rngs: Sequence[np.random.Generator]) -> None:
        super().__init__(games, rngs)
        self.envs: list[FastForagingEnv] = [game.env.game for game in games]  # where a reset leaves its state
        self.fixed = [game.reset_seed is not None for game in games]  # a fixed instance: the same start each time
        first = self.envs[0]
        # step_foraging's settings, in its order: max_steps, penalty, normalize_reward, sight, observe_levels
        self.rules = (
            first._max_episode_steps,
            float(first.penalty),
            bool(first._normalize_reward),
            first.sight,
            bool(first._observe_agent_levels),
        )
        self.field = np.zeros((self.num_replicas, *first.field.shape), dtype=first.field.dtype)
        self.positions = np.zeros((self.num_replicas, self.num_agents, 2), dtype=np.int64)
        self.levels = np.zeros((self.num_replicas, self.num_agents), dtype=np.int64)
        self.steps = np.zeros(self.num_replicas, dtype=np.int64)
        self.food_spawned = np.zeros(self.num_replicas, dtype=np.int64)
        self.seeds = np.zeros(self.num_replicas, dtype=np.int64)
        self.actions = np.zeros((self.num_replicas, first._max_episode_steps, self.num_agents), dtype=np.int64)
        self.action_counts = games[0].action_counts
        self.starts: dict[int, tuple[np.ndarray, ...]] = {}  # a fixed instance's start: field, positions, levels, obs
        for r, env in enumerate(self.envs):
            if env.players[0].position is not None:  # a game never reset holds no state: its first reset gives it
                self._take(r)

    def _take(self, r: int) -> None:
        """Replica r's state from its game (just reset, or replayed to a checkpoint's step)."""
        env, state = self.envs[r], self.games[r].state_dict()
        self.field[r] = env.field
        self.positions[r] = [player.position for player in env.players]
        self.levels[r] = [player.level for player in env.players]
        self.steps[r], self.food_spawned[r], self.seeds[r] = env.current_step, env._food_spawned, state["seed"]
        played = np.asarray(state["actions"], dtype=np.int64).reshape(-1, self.num_agents)
        self.actions[r, : len(played)] = played
        self._obs[r], self._live[r] = state["obs"], state["live"]

    def step(self, actions: np.ndarray) -> BatchStep:
        if not self._live.all():
            raise RuntimeError("an episode is over: reset its replica before the next step")
        joint = np.asarray(actions, dtype=np.int64) % self.action_counts  # PettingZooGame's: a mod n
        self.actions[np.arange(self.num_replicas), self.steps] = joint
        rewards = np.zeros((self.num_replicas, self.num_agents), dtype=np.float32)
        done, food_left = np.zeros(self.num_replicas, dtype=bool), np.zeros(self.num_replicas, dtype=bool)
        self._obs = np.empty_like(self._obs)  # a new array: the last step's observations may still be read
        step_foraging(
            self.field, self.positions, self.levels, joint, self.steps, self.food_spawned, *self.rules, rewards, done,
            food_left, self._obs,
        )  # fmt: skip
        time_up = done & food_left  # the time limit with food left: a truncation
        terminated = np.repeat((done & ~time_up)[:, None], self.num_agents, axis=1)
        truncated = np.repeat(time_up[:, None], self.num_agents, axis=1)
        self._live = np.repeat(~done[:, None], self.num_agents, axis=1)
        nothing = np.zeros((self.num_replicas, self.num_agents), dtype=bool)  # no traps, no obstacles
        none = np.zeros(self.num_replicas, dtype=np.int64)  # no chests
        return BatchStep(self._obs, rewards, terminated, truncated, nothing, nothing, none, none, done)

    def reset(self, which: np.ndarray) -> None:
        for r in self._to_reset(which):
            if r in self.starts:  # a fixed instance's start, its reset seed's alone: kept, not played again
                self.field[r], self.positions[r], self.levels[r], self._obs[r] = self.starts[r]
                self.steps[r], self._live[r] = 0, True
                continue
            self.games[r].reset(self.rngs[r])
            self._take(r)
            if self.fixed[r]:
                self.starts[r] = (
                    self.field[r].copy(),
                    self.positions[r].copy(),
                    self.levels[r].copy(),
                    self._obs[r].copy(),
                )

    def state_dict(self, replica: int) -> dict[str, Any]:
        return {
            "seed": int(self.seeds[replica]),
            "actions": self.actions[replica, : self.steps[replica]].tolist(),
            "obs": self._obs[replica].tolist(),
            "live": self._live[replica].tolist(),
        }

    def load_state_dict(self, replica: int, state: Mapping[str, Any]) -> None:
        super().load_state_dict(replica, state)  # the episode replayed in the replica's own game
        self._take(replica)


def parallel_env(**kwargs: Any) -> LevelBasedForaging:
    """``env=lbf``'s factory: a :class:`LevelBasedForaging` for ``kwargs``."""
    return LevelBasedForaging(**kwargs)
