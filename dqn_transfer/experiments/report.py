"""``REPORT.md`` and its figures, from the study's raw data alone.

:func:`export_data` turns the sweeps under ``OUT/runs/`` into ``OUT/data/`` (:mod:`raw_data`) with a
manifest of how they were made; :func:`write_report` reads ``DATA/`` and writes the report: a summary
of the primary comparisons and their verdicts, then one section per question
(:mod:`~dqn_transfer.experiments.claims`). The report depends on the data and nothing else (no clock,
no checkout state), so regenerating it from committed data gives the committed file byte for byte.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Any

import numpy as np

from dqn_transfer.experiments.claims import SECTIONS
from dqn_transfer.experiments.raw_data import (
    DATA_DIR,
    DATA_SOURCE,
    DataError,
    code_commit,
    export_sweep,
    git_output,
    machine,
    read_data,
    read_manifest,
    write_data,
    write_manifest,
)
from dqn_transfer.experiments.render import Context, Section, render
from dqn_transfer.experiments.sweeps import EXPERIMENTS, PROFILES, RUNS_DIR, ReproduceError, read_stamp

RESULTS_DIR = Path("results") / "v1"  # in the repository: the first edition's report, data and figures
RULES_FILE = RESULTS_DIR / "VERDICT_RULES.md"  # its rules, committed before its runs
SMOKE_MARK = "SMOKE RUN - not evidence"


def code_state() -> dict[str, str]:
    """The commit the runs are made with, and the last commit of the verdict rules before them."""
    rules = git_output("log", "-1", "--format=%h %cs", "--", str(RULES_FILE)) or "not committed"
    return {"commit": code_commit(), "rules_commit": rules}


def export_data(out: Path) -> Path:
    """``OUT/data/``: every experiment's runs under ``OUT/runs/`` as raw data, and the manifest (the
    profile and wall time each sweep's stamp recorded)."""
    data_dir = out / DATA_DIR
    exported, profiles, walls = {}, set(), {}
    for name in EXPERIMENTS:
        sweep = out / RUNS_DIR / name
        if not sweep.is_dir():
            continue
        runs = export_sweep(sweep, name)
        if runs:
            write_data(data_dir / f"{name}.jsonl", runs)
            exported[name] = len(runs)
            stamp = read_stamp(sweep) or {}
            profiles.add(stamp.get("profile", "unknown"))
            if stamp.get("wall_seconds"):
                walls[name] = stamp["wall_seconds"]
    if not exported:
        raise ReproduceError(f"{out / RUNS_DIR} holds no runs of {', '.join(EXPERIMENTS)}: run the experiments first")
    write_manifest(
        data_dir,
        {
            "profile": "/".join(sorted(profiles)),
            **code_state(),
            "machine": machine(),
            "runs": exported,
            "wall_seconds": walls,
            "date": _dt.date.today().isoformat(),
        },
    )
    return data_dir


def _header(manifest: dict[str, Any], smoke: bool) -> list[str]:
    lines = ["# The study answered: knowledge exchange, cooperation and transfer in the treasure hunt", ""]
    if smoke:
        lines += [
            f"> **{PROFILES['quick'].description}** Run `python scripts/reproduce.py --profile full` for evidence.",
            "",
        ]
    walls = manifest.get("wall_seconds", {})
    total = sum(walls.values())
    lines += [
        f"Data: {DATA_SOURCE} (one JSON line per run: its config and every evaluation), "
        f"made on {manifest.get('date', '?')} with the `{manifest.get('profile', '?')}` profile by code "
        f"{manifest.get('commit', '?')} on {manifest.get('machine', '?')}. Verdict rules: `{RULES_FILE}`, "
        f"committed at {manifest.get('rules_commit', '?')}, before these runs.",
        "",
    ]
    if walls:
        lines += [
            "Wall time of the sweeps (2 jobs at a time): "
            + ", ".join(f"{n} {w:.0f} s" for n, w in walls.items())
            + f"; {total / 60:.1f} min in all.",
            "",
        ]
    return lines


def write_report(data_dir: Path, out: Path, seed: int = 0) -> Path:
    """``OUT/REPORT.md`` and its figures from the raw data in ``data_dir``."""
    data_dir, out = Path(data_dir), Path(out)
    manifest = read_manifest(data_dir)
    smoke = "quick" in manifest.get("profile", "")
    ctx = Context(out, np.random.default_rng(seed), SMOKE_MARK if smoke else None)
    sections: list[Section] = []
    for compute, experiments in SECTIONS.values():
        runs = [
            run
            for name in experiments
            if (data_dir / f"{name}.jsonl").exists()
            for run in read_data(data_dir / f"{name}.jsonl")
        ]
        if runs:
            try:
                result = compute(runs, ctx.rng)  # its numbers, then its figures: one generator, a fixed order
                sections.append(render(result, ctx))
            except (KeyError, ValueError, DataError) as err:
                raise ReproduceError(f"cannot analyse the {'/'.join(experiments)} data in {data_dir}: {err}") from err
    if not sections:
        raise ReproduceError(f"{data_dir} holds no run data ({', '.join(f'{n}.jsonl' for n in EXPERIMENTS)})")
    lines = _header(manifest, smoke)
    lines += ["## Summary", "", "| question | primary comparison | result | verdict |", "|---|---|---|---|"]
    lines += [f"| {s.question} | {s.primary} | {s.result} | **{s.verdict}** |" for s in sections]
    lines += [
        "",
        "Each question has one primary comparison, fixed in the verdict rules before the runs; every other "
        "number is exploratory. An interval that contains the null value means no difference was detected "
        "with this many runs, not that there is none. Intervals are 95%: paired differences by map and seed "
        "with t, BCa and percentile-bootstrap intervals; IQM and probability of improvement (P) from rliable's "
        "stratified bootstrap over maps.",
        "",
    ]
    for s in sections:
        lines += [f"## {s.question}", "", s.markdown, ""]
    lines += [
        "## How to reproduce",
        "",
        "```bash",
        f"python scripts/reproduce.py --profile full --out {RESULTS_DIR}     # the runs, the data, this report",
        f"dqn-transfer-report {RESULTS_DIR} --out /tmp/report               # this report again, from its data/",
        "```",
        "",
    ]
    out.mkdir(parents=True, exist_ok=True)
    report = out / "REPORT.md"
    report.write_text("\n".join(lines))
    return report
