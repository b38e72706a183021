"""What a section's runs were run with, read from the configs stored with their data.

The report's prose states these (budgets, evaluations, maps x seeds, team sizes, map sizes, exploration,
exchange schedules) from here, never from hand-written text: a changed experiment config changes the
report's words with its numbers. Where runs disagree, every value is kept (the prose joins them with ``/``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

from dqn_transfer.config.help import group_options, option_values
from dqn_transfer.experiments.raw_data import RunData

# The env keys that make one of claim 2's team-size ladder maps (conf/env/<ladder>/m<m>.yaml).
LADDER_KEYS = ("size", "num_treasures", "num_traps", "num_agents", "complexity")
# claim 2's ladders: the first edition's maps that grow with the team, and the second's of one size.
LADDERS = ("study", "study_fixed")


def values(runs: Sequence[RunData], key: Callable[[dict[str, Any]], Any]) -> tuple[Any, ...]:
    """The distinct values of a config entry over runs, sorted (an absent entry, None, last)."""
    return tuple(sorted({key(r.config) for r in runs}, key=lambda v: (v is None, v)))


@cache
def _ladder() -> tuple[dict[str, Any], ...]:
    """claim 2's study maps, every ladder's rungs, as their env configs give them."""
    rungs = [option for option in group_options("env") if option.split("/")[0] in LADDERS]
    return tuple(option_values("env", option) for option in rungs)


def on_ladder(env: dict[str, Any]) -> bool:
    """Whether an env config is one of claim 2's generated study maps."""
    if env.get("layout") or env.get("layout_file"):
        return False
    return any(all(env.get(k) == rung.get(k) for k in LADDER_KEYS) for rung in _ladder())


@dataclass(frozen=True)
class Evidence:
    """How much evidence: budget and evaluations per run, maps and seeds per condition."""

    total_steps: tuple[int, ...]
    eval_episodes: tuple[int, ...]
    eval_every: tuple[int, ...]
    maps: int
    seeds: int

    @classmethod
    def of(cls, runs: Sequence[RunData]) -> Evidence:
        return cls(
            values(runs, lambda c: c["total_steps"]),
            values(runs, lambda c: c["eval_episodes"]),
            values(runs, lambda c: c["eval_every"]),
            len({r.map_seed for r in runs}),
            len({r.seed for r in runs}),
        )


def _env(config: dict[str, Any]) -> dict[str, Any]:
    return config["env"]


@dataclass(frozen=True)
class Game:
    """The team and the map the runs play."""

    agents: tuple[int, ...]
    chests: tuple[int, ...]
    traps: tuple[int, ...]
    sizes: tuple[int, ...]  # map side
    study_maps: bool  # every map is one of claim 2's generated team-size ladders
    step_reward: tuple[float, ...]
    trap_reward: tuple[float, ...]

    @classmethod
    def of(cls, runs: Sequence[RunData], env_of: Callable[[dict[str, Any]], dict[str, Any]] = _env) -> Game:
        """The game of ``runs``, from each one's env config (``env_of``: another env of its config)."""

        def env(key: str) -> tuple[Any, ...]:
            return values(runs, lambda c: env_of(c).get(key))

        return cls(
            env("num_agents"),
            env("num_treasures"),
            env("num_traps"),
            env("size"),
            all(on_ladder(env_of(r.config)) for r in runs),
            env("step_reward"),
            env("trap_reward"),
        )
