"""Load a trained team to act: its game (the map as it was played) and its learner, from checkpoint files.

:func:`load_team` takes what a user has at hand: a run directory, a replica's directory, a
``checkpoints/`` directory, an exported folder (``dqn-transfer-ckpt export``) or one agent's
checkpoint file. Every file is verified (never unpickled); its meta says the map (its layout), the
rules, the learner and the network, so nothing else is needed. A lone agent file drives every agent
of its map, as a warm start would start them. A team trained on another game (a PettingZoo env) plays
the env its meta names (``env.factory`` and ``env.kwargs``), which must be importable here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dqn_transfer.agents import Learner, make_learner
from dqn_transfer.config import AgentConfig
from dqn_transfer.envs import Game, PettingZooGame, TreasureHuntGame, UnsupportedEnv, make_game
from dqn_transfer.storage.checkpoint import CheckpointError, find_checkpoints, load_agent_checkpoint
from dqn_transfer.storage.run_dir import RunDir


class TeamError(Exception):
    """A path that does not hold a team to load; the message is one user-facing line."""


@dataclass
class TrainedTeam:
    game: Game
    learner: Learner
    files: list[Path]  # agent i's checkpoint (one file for every agent when a lone file was given)
    meta: dict[str, Any]  # agent 0's checkpoint meta: the map, the rules, the learner, steps, last_eval

    @property
    def description(self) -> str:
        meta, game = self.meta, self.game
        if isinstance(game, PettingZooGame):
            return f"{meta['algorithm']} team of {game.num_agents} on {game.factory}, trained {meta['steps']} steps"
        return (
            f"{meta['algorithm']} team of {game.num_agents}, {meta['mode']} mode, {game.size}x{game.size} map, "
            f"trained {meta['steps']} steps"
        )


def team_files(path: Path) -> list[Path]:
    """The agent checkpoints under ``path``, refusing what is not one team."""
    if not path.exists():
        raise TeamError(f"{path}: no such file or directory")
    replicas = RunDir(path).replica_dirs()
    if replicas:
        raise TeamError(
            f"{path} is a run of {len(replicas)} replicas: pass one replica's directory (e.g. {replicas[0]})"
        )
    try:
        return find_checkpoints(path)
    except CheckpointError as err:
        raise TeamError(f"{err} (not a run directory, an exported folder or a checkpoint file)") from None


def trained_game(env: dict[str, Any]) -> Game:
    """The game an agent file's ``env`` meta describes: the PettingZoo env its ``factory`` makes with its
    ``kwargs`` (the recorded instance, if it was fixed), else the treasure hunt on the recorded map.

    :param env: the meta's ``env`` entry.
    """
    if env.get("factory") is not None:
        return PettingZooGame(env["factory"], env["kwargs"], env.get("reset_seed"))
    return make_game(**env)


def load_team(path: str | Path) -> TrainedTeam:
    """The trained team at ``path`` (see the module docstring), greedy-ready on the CPU."""
    path = Path(path)
    files = team_files(path)
    try:
        loaded = [load_agent_checkpoint(file) for file in files]
        meta = loaded[0][1]
        game = trained_game(meta["env"])
        if meta.get("source_task") and isinstance(game, TreasureHuntGame):
            game = game.single_agent_game()
        if len(files) == 1:
            files = files * game.num_agents
            loaded = loaded * game.num_agents
        if len(files) != game.num_agents:
            raise TeamError(f"{path}: holds {len(files)} agent files for a map of {game.num_agents} agents")
        for file, (_, other) in zip(files, loaded):
            if other["env"] != meta["env"] or other["algorithm"] != meta["algorithm"]:
                raise TeamError(f"{file} was trained on another map or with another learner than {files[0].name}")
        learner = make_learner(
            AgentConfig(**meta["agent"]), game.num_agents, game.obs_layout(), game.num_actions, seed=0
        )
        for i, (tensors, _) in enumerate(loaded):
            learner.load_agent_tensors(i, tensors)
    except (CheckpointError, UnsupportedEnv) as err:
        raise TeamError(str(err)) from None
    except (KeyError, TypeError, ValueError) as err:  # a meta this format never writes, or an unloadable map
        raise TeamError(f"{files[0]}: cannot rebuild its team ({type(err).__name__}: {err})") from None
    return TrainedTeam(game, learner, files, meta)
