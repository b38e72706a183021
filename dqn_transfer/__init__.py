"""dqn_transfer: treasure-hunt collective games, tabular and deep Q-learners, transfer learning.

Importing the package registers the Gymnasium environment ``TreasureHunt-v0`` (lazily: the entry
point is only imported by ``gymnasium.make``). Nothing heavy (torch) is imported here.
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

if "TreasureHunt-v0" not in registry:  # importing twice (e.g. reloads) must not re-register
    register(id="TreasureHunt-v0", entry_point="dqn_transfer.envs.single_agent:TreasureHuntEnv")
