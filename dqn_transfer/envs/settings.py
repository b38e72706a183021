"""The game's settings and their defaults, in one dataclass.

``make_game(**kwargs)``, the PettingZoo and Gymnasium faces and the trainer's ``env`` config group
all take exactly these keys (the config schema *is* this dataclass), so a default is written once,
beside the one-line description that ``--help`` shows.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Dict, Optional

from dqn_transfer.documented import documented
from dqn_transfer.enums import Contention, Mode, ObsEncoding, RewardMode


@dataclass
class EnvConfig:
    """One treasure-hunt game. A ``layout`` / ``layout_file`` fixes the size and the counts."""

    size: int = documented(6, "grid side n")
    num_treasures: int = documented(2, "chests k")
    num_traps: Optional[int] = documented(None, "traps; null: k")
    num_agents: Optional[int] = documented(None, "agents (at most 10); null: k")
    complexity: float = documented(0.1, "obstacle fraction Rc: round(Rc * n * n) obstacles")
    map_seed: int = documented(
        0,
        "seeds the generated map, fixed for a run (episodes reset agents and chests only); with env.fixed_start, "
        "another game's reset seed",
    )
    contention: Contention = documented(
        Contention.any,
        "generated maps only: any map of the seed, or its first candidate where every agent shares its nearest "
        "chest (high) or none does (low)",
    )
    layout: Optional[str] = documented(None, "an ASCII map (rows of . # T X 0-9) instead of a generated one")
    layout_file: Optional[str] = documented(None, "a path to an ASCII map")
    max_steps: Optional[int] = documented(None, "truncation horizon in joint steps; null: n * n")
    mode: Mode = documented(
        Mode.competitive,
        "how `treasures` is kept: competitive (no communication), "
        "cooperative (announcements), deliberative (a coordinator)",
    )
    reward_mode: RewardMode = documented(RewardMode.individual, "team: every live agent receives the step's sum")
    obs_encoding: ObsEncoding = documented(
        ObsEncoding.onehot, "`position` as one-hot of the cell or (row, col) in [0, 1]"
    )
    view_radius: int = documented(0, "> 0 adds an egocentric (2r+1)^2 `view` segment")
    treasure_reward: float = documented(100.0, "entering a full chest (the agent is then done)")
    trap_reward: float = documented(-100.0, "entering a trap (the agent is then done)")
    step_reward: float = documented(-1.0, "every other move, an empty chest included")
    render_mode: Optional[str] = documented(
        None, "ansi | rgb_array | human for the faces' render(); training does not render"
    )
    factory: Optional[str] = documented(
        None,
        "another game instead of the treasure hunt: PACKAGE.MODULE:CALLABLE returning a PettingZoo ParallelEnv "
        "(docs/your_own_environment.md); the keys above then do not apply",
    )
    kwargs: Dict[str, Any] = documented(factory=dict, doc="keyword arguments of env.factory")
    fixed_start: bool = documented(
        False,
        "env.factory's game: every episode resets the env with seed env.map_seed, one fixed instance per map "
        "seed (replicas.maps=K: K instances); false: each episode a new reset seed",
    )


# The keys of another game (a PettingZoo env) instead of the treasure hunt: they are not the treasure hunt's, so
# they stay out of its games, its maps and its pretraining cache keys.
FACTORY_KEYS = ("factory", "kwargs", "fixed_start")
# env=pettingzoo's env.factory until its user names one (Hydra's ??? would not override the schema's null: the
# run would silently be the treasure hunt's).
FACTORY_PLACEHOLDER = "PACKAGE.MODULE:CALLABLE"
# The treasure hunt's own keys.
ENV_KEYS = tuple(f.name for f in fields(EnvConfig) if f.name not in FACTORY_KEYS)
# The keys that shape the map itself; the rest are rules, observations and rewards.
MAP_KEYS = (
    "size",
    "num_treasures",
    "num_traps",
    "num_agents",
    "complexity",
    "map_seed",
    "contention",
    "layout",
    "layout_file",
)
# Map keys that only choose which map a seed generates: a cache key that holds the map's layout leaves
# them out (which keeps the entries cached before they existed valid).
MAP_CHOICE_KEYS = ("contention",)
# The game's rules: the keys a game is built with besides its map (render_mode belongs to the faces).
RULE_KEYS = tuple(key for key in ENV_KEYS if key not in MAP_KEYS and key != "render_mode")
DEFAULTS = EnvConfig()
