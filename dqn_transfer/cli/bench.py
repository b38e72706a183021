"""``dqn-transfer-bench`` / ``python -m dqn_transfer.cli.bench``: the benchmark table, and its JSON document.

    dqn-transfer-bench [--profile full|quick] [--sections env,training,team,update,lone,replicas,tabular]
                       [--out outputs/bench.json] [--seed 0] [--repeats 3] [--threads 1] [--baseline DIR]

(``--quick`` = ``--profile quick``; ``--only SECTION``, repeatable, adds to ``--sections``.) Measures our
environment, trainer and learner against PettingZoo's API, Stable-Baselines3 and bare PyTorch, in
process and as whole processes, and the study's tabular jobs against an earlier checkout
(:mod:`dqn_transfer.benchmark`, whose suite module explains the method). The table goes to
stdout, progress to stderr, and everything (the raw per-repeat figures and the machine) to ``--out``,
written atomically. What would fail after minutes of measuring (SB3 missing, ``--out`` not writable)
or a ``--baseline`` that is not a checkout of the project, is checked first: one ``error:`` line and exit
code 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from importlib.util import find_spec
from pathlib import Path

from dqn_transfer.benchmark.suite import NEEDS_SB3, PROFILES, SECTIONS, run_benchmark
from dqn_transfer.benchmark.tables import render_markdown
from dqn_transfer.storage.checkpoint import CheckpointError, atomic_write


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def section_list(text: str) -> list[str]:
    """``lone,replicas`` -> ``["lone", "replicas"]``, each one a section name."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in SECTIONS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated sections from {', '.join(SECTIONS)}, got {text!r}")
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dqn-transfer-bench",
        description="Benchmark table: env throughput, DQN training vs SB3, team size, gradient-update overhead, "
        "whole processes (one learner vs SB3 and bare PyTorch; replica sweeps vs SB3), the study's tabular jobs "
        "against an earlier checkout.",
    )
    parser.add_argument(
        "--profile",
        choices=PROFILES,
        default="full",
        help="full (default) or quick: small sizes, a smoke run (a few minutes)",
    )
    parser.add_argument("--quick", dest="profile", action="store_const", const="quick", help="--profile quick")
    parser.add_argument(
        "--out", type=Path, default=Path("outputs/bench.json"), help="JSON output path (default outputs/bench.json)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--repeats",
        type=positive_int,
        default=3,
        help="interleaved repeats per measurement; the median is reported (default 3)",
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        default=1,
        help="torch threads of sections 1-4 (default 1, fastest for these tiny networks); section 4 also times "
        "torch's default thread count. Section 5's processes and section 6's process of ours run on one thread",
    )
    parser.add_argument(
        "--sections",
        type=section_list,
        default=[],
        help=f"comma-separated sections to measure (default: all: {','.join(SECTIONS)})",
    )
    parser.add_argument(
        "--only",
        choices=SECTIONS,
        action="append",
        default=[],
        help="measure this section too (repeatable; the same as listing it in --sections)",
    )
    parser.add_argument(
        "--baseline",
        type=Path,
        help="section tabular: a checkout of an earlier commit of this project (e.g. `git worktree add "
        "/tmp/v0 COMMIT`), whose train.py runs beside ours on the same command line",
    )
    return parser


def check_ready(out: Path, sections: list[str], baseline: Path | None = None) -> str | None:
    """What would make the run fail, as a message (None: ready): SB3 absent, --out unwritable, a
    --baseline that is no checkout of the project or that no chosen section uses."""
    if any(section in NEEDS_SB3 for section in sections) and find_spec("stable_baselines3") is None:
        return "the benchmark compares against Stable-Baselines3: pip install -e '.[dev]'"
    if baseline is not None:
        if "tabular" not in sections:
            return "--baseline is run by the tabular section only: add --only tabular"
        if not (baseline / "train.py").is_file() or not (baseline / "dqn_transfer").is_dir():
            return f"--baseline {baseline}: not a checkout of dqn_transfer (no train.py and dqn_transfer/ there)"
    if out.is_dir():
        return f"--out {out} is a directory; give a file path such as {out / 'bench.json'}"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        return f"cannot create {out.parent}: {err.strerror}"
    try:  # a real write: os.access says yes to root even where writing fails (e.g. /proc)
        with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".probe"):
            pass
    except OSError as err:
        return f"cannot write into {out.parent}: {err.strerror}"
    return None


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    chosen = {*args.sections, *args.only}
    sections = [s for s in SECTIONS if s in chosen] if chosen else list(SECTIONS)
    baseline = None if args.baseline is None else args.baseline.resolve()
    problem = check_ready(args.out, sections, baseline)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 1
    start = time.perf_counter()
    results = run_benchmark(args.profile, args.seed, args.repeats, args.threads, sections=sections, baseline=baseline)
    total_seconds = time.perf_counter() - start
    table = render_markdown(results)
    print(table)
    document = {**results, "total_seconds": total_seconds, "markdown": table}
    try:
        atomic_write(args.out, (json.dumps(document, indent=2) + "\n").encode())
    except CheckpointError as err:  # atomic_write words its failure for checkpoints
        print(f"error: could not save the results (the table is above): {err}", file=sys.stderr)
        return 1
    print(f"wrote {args.out} ({total_seconds:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
