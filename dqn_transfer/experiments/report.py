"""``OUT/REPORT.md``: the study's reproduction report, from the sweeps under ``OUT``.

The runs of ``OUT/{fig1,fig2,transfer}`` (whichever exist) are read back from their run
directories, never live objects; a directory that is not a usable run (a job that never evaluated,
one without a readable config) is skipped with a :class:`~dqn_transfer.analysis.runs.SkippedRun`
warning. Each experiment becomes a section of :mod:`dqn_transfer.experiments.claims` with its
verdict, figures beside the report. A summary table comes first; a ``quick`` profile's report says in
its first lines that it is not evidence.
"""

from __future__ import annotations

import datetime as _dt
import json
import subprocess
from pathlib import Path

import numpy as np

from dqn_transfer.analysis.runs import EvaluationError, load_runs
from dqn_transfer.experiments.claims import SECTIONS, Section
from dqn_transfer.experiments.sweeps import EXPERIMENTS, PROFILES, STAMP_FILE, ReproduceError

PACKAGE_DIR = Path(__file__).resolve().parent


def _git_describe() -> str:
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=PACKAGE_DIR, capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=PACKAGE_DIR, capture_output=True,
                               text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return commit + (" (with uncommitted changes)" if dirty else "")


def write_report(out: Path, profile: str | None = None, seed: int = 0) -> Path:
    """Analyse ``OUT/{fig1,fig2,transfer}`` (whichever exist) into ``OUT/REPORT.md`` and PNG figures."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    sections: dict[str, Section] = {}
    stamps, run_counts = {}, {}
    for name in EXPERIMENTS:
        runs = load_runs(out / name)  # unusable runs are skipped, each with a warning
        if not runs:
            continue
        run_counts[name] = len(runs)
        stamp_path = out / name / STAMP_FILE
        stamps[name] = json.loads(stamp_path.read_text()) if stamp_path.exists() else {}
        try:
            sections[name] = SECTIONS[name](out, runs, rng)
        except (EvaluationError, ValueError, KeyError) as err:
            raise ReproduceError(f"cannot analyse {out / name}: {err}") from err
    if not sections:
        raise ReproduceError(f"{out} holds no runs of {', '.join(EXPERIMENTS)}: run the experiments first")
    profiles = {s.get("profile") for s in stamps.values()} - {None}
    if profile is not None:
        profiles.add(profile)
    smoke = "quick" in profiles
    lines = ["# Reproduction report: Transfer Learning Approach for Autonomous Agents in Collective Games", ""]
    if smoke:
        lines += [f"> **{PROFILES['quick'].description}** Run `python scripts/reproduce.py --profile full` "
                  "for evidence.", ""]
    lines += [f"Generated {_dt.datetime.now().isoformat(timespec='seconds')} from the runs under `{out}`; "
              f"profile: {', '.join(sorted(profiles)) or 'unknown'}; code: {_git_describe()}.", ""]
    walls = {n: s.get("wall_seconds") for n, s in stamps.items() if s.get("wall_seconds")}
    if walls:
        lines += ["Sweep wall times: " + ", ".join(f"{n} {w:.0f} s" for n, w in walls.items()) + ".", ""]
    lines += ["## Summary", "", "| claim | verdict | key numbers: mean [95% CI] | evidence |", "|---|---|---|---|"]
    for name in EXPERIMENTS:
        if name in sections:
            s = sections[name]
            lines.append(f"| {s.claim} | {s.verdict} | {s.headline} | {s.evidence} |")
        else:
            lines.append(f"| (experiment `{name}`) | not run | — | — |")
    lines += ["", "Verdicts follow the rules stated under each claim, fixed before looking at the data. A CI that "
              "contains 0 means no difference was detected with this many seeds, not that there is none. "
              "Intervals are 95% percentile bootstraps over seeds (10,000 resamples); differences between "
              "conditions pair runs of the same seed.", ""]
    if any(count < 10 for count in run_counts.values()) and not smoke:
        lines += ["> Some conditions rest on fewer than 10 seeds: treat their verdicts as preliminary.", ""]
    for name, s in sections.items():
        lines += [f"## Claim {s.claim}", "", s.markdown, ""]
    lines += ["## How to reproduce", "",
              "```bash",
              "python scripts/reproduce.py --profile quick --out /tmp/repro_quick   # smoke run, minutes",
              "python scripts/reproduce.py --profile full --out results             # evidence, ~30 min on 2 cores",
              "python scripts/reproduce.py --profile full --out results --launcher submitit_slurm \\",
              "    --extra hydra.launcher.partition=PART --extra hydra.launcher.timeout_min=120",
              "```", "",
              "The exact command of every sweep is the first line of `logs/<experiment>.log`; each run's "
              "config is in its `.hydra/` directory.", ""]
    report = out / "REPORT.md"
    report.write_text("\n".join(lines))
    return report
