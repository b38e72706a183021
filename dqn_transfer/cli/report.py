"""Reproduce the study's three claims: run the sweeps, then write ``OUT/REPORT.md`` and figures.

    python scripts/reproduce.py --profile quick --out /tmp/repro_quick   # smoke run: minutes, 2-3 seeds
    python scripts/reproduce.py --profile full --out results/            # the evidence: >= 10 seeds, ~30 min on 2 cores
    python scripts/reproduce.py --profile full --out results/ --launcher submitit_slurm \\
        --extra hydra.launcher.partition=PART --extra hydra.launcher.timeout_min=120
    python scripts/reproduce.py --out results/ --report-only             # re-analyse runs already there
    python scripts/reproduce.py --write-maps maps/                        # only the Figure 2 team maps

(``python -m dqn_transfer.cli.report`` takes the same arguments.) Each experiment is one Hydra
multirun of ``python -m dqn_transfer.cli.train -m experiment=<name>`` (``conf/experiment/``) into
``OUT/<name>/`` (a subprocess; ``--launcher joblib``, the default, runs ``--n-jobs`` jobs at a time;
without the ``sweep`` extra the default is Hydra's basic launcher, one job at a time). The ``full``
profile uses the experiment files' own step counts; ``quick`` shrinks them and the seeds. Then the
run directories are read back (``.hydra/config.yaml`` + ``metrics.jsonl``, never live objects) and
the report says, for each claim, whether the data support it, by a rule fixed in advance:

1. one treasure: cooperation gives no advantage over competition (``fig1``);
2. complex map, growing team: deliberative > cooperative > competitive (``fig2``);
3. transfer from a trained agent speeds up learning (``transfer``).

Figure 2 compares team sizes on the SAME map: the 4-agent map is generated once and its m-agent
versions drop the start digits >= m (``OUT/maps/fig2_m{m}.txt``); changing ``env.num_agents``
instead would generate a different map for every team size.

A sweep directory already complete for the same settings is reused (so a failed report or a second
``--only`` does not rerun it); one holding other or unfinished runs is an error, never overwritten.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from dqn_transfer.analysis.runs import skipped_runs_on_stderr
from dqn_transfer.experiments.report import write_report
from dqn_transfer.experiments.sweeps import EXPERIMENTS, PROFILES, ReproduceError, choose_launcher, run_experiment
from dqn_transfer.experiments.team_maps import write_team_maps


def main(argv: list[str] | None = None) -> int:
    """Run the sweeps and write the report; exit 1 with one ``error:`` message on a failure."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])
    parser.add_argument("--profile", choices=sorted(PROFILES), default="quick")
    parser.add_argument("--out", type=Path, help="output directory (sweeps, figures, REPORT.md)")
    parser.add_argument("--only", default=",".join(EXPERIMENTS),
                        help=f"comma-separated subset of {','.join(EXPERIMENTS)} (default: all)")
    parser.add_argument("--launcher", default=None,
                        help="Hydra launcher: joblib (default; the sweep extra, else basic), basic (one job at "
                             "a time), submitit_slurm (the slurm extra), ...")
    parser.add_argument("--n-jobs", type=int, default=2, help="parallel jobs with --launcher joblib (default 2)")
    parser.add_argument("--extra", action="append", default=[], metavar="OVERRIDE",
                        help="extra Hydra override for every sweep, e.g. hydra.launcher.partition=PART (repeatable)")
    parser.add_argument("--report-only", action="store_true", help="do not run anything; analyse OUT as it is")
    parser.add_argument("--write-maps", type=Path, metavar="DIR",
                        help="only write the Figure 2 team-size maps (fig2_m1..4.txt) into DIR")
    args = parser.parse_args(argv)
    try:
        if args.write_maps is not None:
            for path in write_team_maps(args.write_maps):
                print(path)
            return 0
        if args.out is None:
            parser.error("--out is required")
        only = [name.strip() for name in args.only.split(",") if name.strip()]
        unknown = [name for name in only if name not in EXPERIMENTS]
        if unknown:
            raise ReproduceError(f"--only: unknown experiment(s) {', '.join(unknown)} (choose from {', '.join(EXPERIMENTS)})")
        if args.n_jobs < 1:
            raise ReproduceError(f"--n-jobs must be >= 1, got {args.n_jobs}")
        launcher = None if args.report_only else choose_launcher(args.launcher)  # refused before anything runs
        out = args.out.expanduser().resolve()
        out.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        if not args.report_only:
            print(f"profile {args.profile}: {PROFILES[args.profile].description}", flush=True)
            for name in only:
                run_experiment(name, args.profile, out, launcher, args.n_jobs, args.extra)
        with skipped_runs_on_stderr():
            report = write_report(out, None if args.report_only else args.profile)
    except ReproduceError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print(f"wrote {report} ({time.perf_counter() - start:.0f} s in total)")
    for line in report.read_text().splitlines():
        if line.startswith("| ") and "**" in line:
            print("  " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
