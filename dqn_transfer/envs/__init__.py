"""The treasure-hunt game: maps, the numpy core, and its PettingZoo and Gymnasium faces; and any other
PettingZoo game behind the same interface (:mod:`.pettingzoo_game`)."""

from dqn_transfer.envs.game import StepOutcome, TreasureHuntGame, make_game
from dqn_transfer.envs.maps import GridMap, generate_layout, parse_layout, resolve_map
from dqn_transfer.envs.pettingzoo_game import PettingZooGame, UnsupportedEnv
from dqn_transfer.envs.single_agent import TreasureHuntEnv
from dqn_transfer.envs.treasure_hunt import TreasureHuntParallelEnv

# What the trainer plays: the treasure hunt, or a PettingZoo env named by env.factory.
Game = TreasureHuntGame | PettingZooGame

__all__ = [
    "Game",
    "GridMap",
    "PettingZooGame",
    "TreasureHuntEnv",
    "StepOutcome",
    "TreasureHuntGame",
    "TreasureHuntParallelEnv",
    "UnsupportedEnv",
    "generate_layout",
    "make_game",
    "parse_layout",
    "resolve_map",
]
