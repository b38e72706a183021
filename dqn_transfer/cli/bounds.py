"""``python -m dqn_transfer.cli.bounds``: the oracle's, the greedy team's and the random team's
evaluation records on one map.

    python -m dqn_transfer.cli.bounds --map-seed 0 --size 8 --num-treasures 4 --num-traps 4 \\
        --num-agents 4 --mode cooperative --episodes 5

One JSON line per bound (:mod:`dqn_transfer.evaluation.bounds`); bad input is one ``error:`` line.
"""

from __future__ import annotations

import argparse
import json
import typing
from dataclasses import fields
from enum import Enum

from dqn_transfer.cli.console import OneLineErrors, exit_with
from dqn_transfer.documented import HELP
from dqn_transfer.enums import Bound, values
from dqn_transfer.envs.game import make_game
from dqn_transfer.envs.settings import ENV_KEYS, EnvConfig
from dqn_transfer.evaluation.bounds import evaluate_bound


def _env_options(parser: argparse.ArgumentParser) -> None:
    """One ``--key`` per treasure-hunt key of EnvConfig (``num_agents`` as ``--num-agents``); a key left
    out is not given, as in ``make_game``."""
    hints = typing.get_type_hints(EnvConfig)
    documented = {field.name: field.metadata[HELP] for field in fields(EnvConfig)}
    for key in ENV_KEYS:
        if key == "render_mode":
            continue  # the bounds render nothing
        kind = next((arg for arg in typing.get_args(hints[key]) if arg is not type(None)), hints[key])
        flag = "--" + key.replace("_", "-")
        if isinstance(kind, type) and issubclass(kind, Enum):
            parser.add_argument(flag, dest=key, choices=values(kind), help=documented[key])
        else:
            parser.add_argument(flag, dest=key, type=kind, help=documented[key])


def main(argv: list[str] | None = None) -> int:
    """Print the oracle's and the greedy team's evaluation records as JSON lines."""
    parser = OneLineErrors(description=__doc__.split("\n\n")[0])
    _env_options(parser)
    parser.add_argument("--episodes", type=int, default=5, help="evaluation episodes per bound (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="the evaluation seed (it draws chest ties)")
    args = vars(parser.parse_args(argv))
    episodes, seed = args.pop("episodes"), args.pop("seed")
    if episodes < 1:
        parser.error(f"--episodes must be at least 1, got {episodes}")
    try:
        game = make_game(**{key: value for key, value in args.items() if value is not None})
    except ValueError as err:
        parser.error(str(err))
    for kind in Bound:
        print(json.dumps({"bound": kind.value, **evaluate_bound(game, kind, episodes, seed)}))
    return 0


if __name__ == "__main__":
    exit_with(main)
