"""Claim 1 settled exactly: optimal team returns of small one-chest maps in every mode (docs/claim1_exact.md).

    python -m dqn_transfer.cli.claim1_exact [--maps 4x4 5x5 claim1:0 ...] [--max-steps N]

Prints a Markdown table (:func:`dqn_transfer.evaluation.value_iteration.format_table`): per map, the joint
optimum by value iteration and each mode's own-observation team replayed through the game.
"""

from __future__ import annotations

from dqn_transfer.cli.console import OneLineErrors, exit_with
from dqn_transfer.evaluation.value_iteration import DEFAULT_MAPS, format_table, map_values, named_map


def main(argv: list[str] | None = None) -> int:
    """Print the table; bad input is one ``error:`` line and exit code 2."""
    parser = OneLineErrors(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--maps",
        nargs="+",
        default=list(DEFAULT_MAPS),
        metavar="MAP",
        help="4x4, 5x5 (small hand-made maps) or claim1:SEED (the claim-1 map of that map seed); "
        "default: 4x4 5x5 claim1:0 .. claim1:9",
    )
    parser.add_argument("--max-steps", type=int, default=None, help="the horizon (default: n * n, the game's)")
    args = parser.parse_args(argv)
    try:
        maps = [(name, named_map(name)) for name in args.maps]  # every name checked before any work
        results = [map_values(name, grid_map, args.max_steps) for name, grid_map in maps]
    except ValueError as err:  # an unknown map name, a map that is too large, a bad horizon
        parser.error(str(err))
    print(format_table(results))
    return 0


if __name__ == "__main__":
    exit_with(main)
