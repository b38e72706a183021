"""The paired analysis's ``REPORT.md`` and its figures (the first edition's), from its raw data alone.

The report depends on the data and nothing else (no clock, no checkout state), so regenerating it from
committed data gives the committed file byte for byte.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dqn_transfer.experiments.claims import SECTIONS
from dqn_transfer.experiments.edition import Edition
from dqn_transfer.experiments.raw_data import DATA_SOURCE, DataError, Evidence, read_evidence, read_experiment
from dqn_transfer.experiments.render import Context, Section, render
from dqn_transfer.experiments.sweeps import ReproduceError


def _header(edition: Edition, evidence: Evidence) -> list[str]:
    lines = [f"# {edition.title}", ""]
    if evidence.smoke:
        lines += [f"> **{edition.profiles['quick'].description}** {edition.report['smoke_advice']}", ""]
    records, manifest = evidence.records, evidence.manifest

    def made(key: str) -> str:  # one value, or each experiment's
        return "/".join(sorted({str(r.get(key, "?")) for r in records.values()})) or "?"

    walls = {name: r["wall_seconds"] for name, r in records.items() if r.get("wall_seconds")}
    lines += [
        f"Data: {DATA_SOURCE} (one JSON line per run: its config and every evaluation), "
        f"made on {made('date')} with the `{made('profile')}` profile by code "
        f"{made('commit')} on {made('machine')}. Verdict rules: `{edition.rules}`, "
        f"committed at {manifest.get('rules_commit', '?')}, before these runs.",
        "",
    ]
    if walls:
        lines += [
            "Wall time of the sweeps (2 jobs at a time): "
            + ", ".join(f"{n} {w:.0f} s" for n, w in walls.items())
            + f"; {sum(walls.values()) / 60:.1f} min in all.",
            "",
        ]
    return lines


def write_report(edition: Edition, results: Path, out: Path) -> Path:
    """``OUT/REPORT.md`` and its figures from the raw data in ``RESULTS/data/``."""
    evidence = read_evidence(results)
    data_dir = evidence.data
    ctx = Context(Path(out), np.random.default_rng(0), evidence.watermark)
    sections: list[Section] = []
    for compute, experiments in SECTIONS.values():
        runs = [run for name in experiments for run in read_experiment(data_dir, name)]
        if runs:
            try:
                result = compute(runs, ctx.rng)  # its numbers, then its figures: one generator, a fixed order
                sections.append(render(result, ctx))
            except (KeyError, ValueError, DataError) as err:
                raise ReproduceError(f"cannot analyse the {'/'.join(experiments)} data in {data_dir}: {err}") from err
    if not sections:
        raise ReproduceError(f"{data_dir} holds no run data ({', '.join(f'{n}.jsonl' for n in edition.experiments)})")
    lines = _header(edition, evidence)
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
        *edition.report["reproduce"],
        "```",
        "",
    ]
    Path(out).mkdir(parents=True, exist_ok=True)
    report = Path(out) / "REPORT.md"
    report.write_text("\n".join(lines))
    return report
