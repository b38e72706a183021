"""``python -m dqn_transfer.cli.contention``: the contention of env options' generated maps, per ``env.contention``.

    python -m dqn_transfer.cli.contention study_fixed/m2 study_fixed/m3 study_fixed/m4 study_fixed/m6 --maps 30

For each env option and each of ``any``, ``high``, ``low``: the maps of map seeds ``--map-seed ..
--map-seed + --maps - 1``, their mean contention and mean fraction of agents whose optimal chest is not
their nearest (:mod:`dqn_transfer.evaluation.contention`), and the CPU time their generation took, as a
Markdown table. Bad input is one ``error:`` line.
"""

from __future__ import annotations

from dqn_transfer.cli.console import OneLineErrors, exit_with
from dqn_transfer.config.help import group_options, option_values
from dqn_transfer.enums import Contention, values
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.evaluation.contention import contention_rows, contention_table


def main(argv: list[str] | None = None) -> int:
    """Print the table of the env options' maps."""
    parser = OneLineErrors(description=__doc__.split("\n\n")[0])
    # The treasure hunt's options: those that set its keys only (not another game's factory, nor a whole run).
    hunts = [option for option in group_options("env") if set(option_values("env", option)) <= set(ENV_KEYS)]
    parser.add_argument("envs", nargs="+", metavar="ENV", choices=hunts, help="env options, e.g. study_fixed/m4")
    parser.add_argument("--maps", type=int, default=30, help="map seeds per option and contention (default 30)")
    parser.add_argument("--map-seed", type=int, default=0, help="the first map seed (default 0)")
    parser.add_argument(
        "--contention", nargs="+", choices=values(Contention), default=values(Contention), help="(default: all)"
    )
    args = parser.parse_args(argv)
    if args.maps < 1 or args.map_seed < 0:
        parser.error(f"--maps must be at least 1 and --map-seed at least 0, got {args.maps} and {args.map_seed}")
    seeds = range(args.map_seed, args.map_seed + args.maps)
    rows = []
    for env in args.envs:
        try:
            rows += contention_rows(env, option_values("env", env), seeds, [Contention(c) for c in args.contention])
        except ValueError as err:
            parser.error(f"env={env}: {err}")
    print(contention_table(rows))
    return 0


if __name__ == "__main__":
    exit_with(main)
