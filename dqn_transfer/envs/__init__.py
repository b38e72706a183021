"""The treasure-hunt game: maps, the numpy core, and its PettingZoo and Gymnasium faces."""

from dqn_transfer.envs.game import StepOutcome, TreasureHuntGame, make_game
from dqn_transfer.envs.maps import GridMap, generate_layout, parse_layout, resolve_map
from dqn_transfer.envs.single_agent import TreasureHuntEnv
from dqn_transfer.envs.treasure_hunt import TreasureHuntParallelEnv

__all__ = [
    "GridMap",
    "TreasureHuntEnv",
    "StepOutcome",
    "TreasureHuntGame",
    "TreasureHuntParallelEnv",
    "generate_layout",
    "make_game",
    "parse_layout",
    "resolve_map",
]
