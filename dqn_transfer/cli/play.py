"""Watch a trained team play greedy episodes, as a GIF or in the terminal.

    dqn-transfer-play RUN_DIR [--episodes N] [--seed S] [--gif OUT.gif] [--ansi]

(also ``python -m dqn_transfer.play`` and ``python -m dqn_transfer.cli.play``). RUN_DIR is a run
directory, a replica's directory, an exported folder (``dqn-transfer-ckpt export``) or one agent's
checkpoint file (it then drives every agent of its map). Each episode's outcome is printed; ``--gif``
writes every frame of every episode (one per step plus the first: the grid, obstacles, traps, chests
full and emptied, the agents numbered in their colours with their trails, the step and the team
return), ``--ansi`` replays them in the terminal. Episode i draws its chest ties from (S, i).

A team trained on another game (a PettingZoo env, ``env=lbf``, ``env=mpe_spread``, ``env=pettingzoo``)
plays that env, episode i reset with a seed drawn from (S, i). ``--gif`` then writes the env's own
frames (``render_mode="rgb_array"``) with the step and the team return under each; an env that cannot
draw one (no such render mode, or no display for its renderer) is refused in one ``error:`` line, as
is ``--ansi`` (the text grid is the treasure hunt's).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from dqn_transfer.cli.console import exit_with
from dqn_transfer.envs import PettingZooGame, UnsupportedEnv
from dqn_transfer.evaluation.watch import (
    RecordedEpisode,
    Watched,
    gif_bytes,
    outcome,
    replay_in_terminal,
    watch_team,
)
from dqn_transfer.sharing.team import TeamError, load_team
from dqn_transfer.storage.checkpoint import CheckpointError, atomic_write


class PlayError(Exception):
    """Bad input to the command; the message is one user-facing line."""


def writable_gif_path(path: Path) -> Path:
    """``path`` if a GIF can be written there, checked before any episode is played."""
    if path.is_dir():
        raise PlayError(f"--gif {path}: is a directory; give a file name such as {path / 'episode.gif'}")
    folder = path.parent
    if not folder.is_dir():
        raise PlayError(f"--gif {path}: the directory {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PlayError(f"--gif {path}: cannot write in {folder} (permission denied)")
    return path


def main(argv: list[str] | None = None) -> int:
    """Play, print each episode's outcome, write or show the frames; one ``error:`` line on bad input."""
    parser = argparse.ArgumentParser(
        prog="dqn-transfer-play",
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 2)[2],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "path",
        metavar="RUN_DIR",
        type=Path,
        help="a run or replica directory, an exported folder, or one agent's checkpoint file",
    )
    parser.add_argument("--episodes", type=int, default=1, metavar="N", help="greedy episodes to play (default 1)")
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        metavar="S",
        help="seeds the episodes' chest ties (another game: their resets; default 0)",
    )
    parser.add_argument("--gif", type=Path, metavar="OUT.gif", help="write every frame of every episode to this GIF")
    parser.add_argument("--ansi", action="store_true", help="replay the episodes in the terminal")
    args = parser.parse_args(argv)
    try:
        if args.episodes < 1:
            raise PlayError(f"--episodes must be >= 1, got {args.episodes}")
        gif = writable_gif_path(args.gif) if args.gif is not None else None
        team = load_team(args.path)
        game = team.game
        if isinstance(game, PettingZooGame):
            if args.ansi:
                raise PlayError(f"--ansi prints the treasure hunt's grid; {game.factory} is another game (use --gif)")
            if gif is not None:
                game = game.drawing()
        print(f"{team.description}: {args.episodes} greedy episode(s) from {args.path}")
        episodes: Sequence[Watched] = watch_team(game, team.learner, args.episodes, args.seed)
        if args.ansi:
            replay_in_terminal([e for e in episodes if isinstance(e, RecordedEpisode)])  # --ansi: the treasure hunt's
        else:
            for number, episode in enumerate(episodes, 1):
                print(f"episode {number}: {outcome(episode)}")
        if gif is not None:
            atomic_write(gif, gif_bytes(episodes))
            print(f"wrote {gif} ({sum(len(e.frames) for e in episodes)} frames)")
    except (PlayError, TeamError, CheckpointError, UnsupportedEnv) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


def run() -> None:
    """Console-script entry: ``main`` with a quiet exit when the reader of stdout goes away."""
    exit_with(main)


if __name__ == "__main__":
    run()
