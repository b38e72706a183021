"""What the reports of the registered editions share: a report's opening, the table of how its data were
made, a table a stage wrote, a p-value's text."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from dqn_transfer.experiments.edition import Edition
from dqn_transfer.experiments.raw_data import SMOKE_MARK, Evidence


def p_text(p: float) -> str:
    """A p-value to three significant digits; ``n/a`` where there is none (no spread)."""
    return "n/a" if not math.isfinite(p) else f"{p:.3g}"


def include(path: Path) -> list[str]:
    """A table a stage wrote (``maps.md``, ``tuning.md``), or a line saying it is missing."""
    return path.read_text().rstrip("\n").splitlines() + [""] if path.exists() else [f"({path.name} is missing)", ""]


def opening(edition: Edition, evidence: Evidence, missing: Sequence[str], missing_note: str = ".") -> list[str]:
    """A report's title, and its warnings: smoke data, experiments not yet run (``missing``)."""
    smoke = f"> **{SMOKE_MARK}**: the quick profile checks the pipeline; its numbers are not evidence."
    return [
        f"# {edition.title}",
        "",
        *([smoke, ""] if evidence.smoke else []),
        *([f"> **Not yet run**: {', '.join(missing)}{missing_note}", ""] if missing else []),
    ]


def records_table(evidence: Evidence) -> list[str]:
    """How each experiment's data were made: runs, date, profile, code commit, machine, wall time."""
    return [
        "| experiment | runs | made on | profile | by code | on | wall time |",
        "|---|---:|---|---|---|---|---:|",
        *[
            f"| {name} | {r.get('runs', '?')} | {r.get('date', '?')} | {r.get('profile', '?')} "
            f"| {r.get('commit', '?')} | {r.get('machine', '?')} | {float(r.get('wall_seconds', 0)) / 60:.1f} min |"
            for name, r in evidence.records.items()
        ],
        "",
    ]
