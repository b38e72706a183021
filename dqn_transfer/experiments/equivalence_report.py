"""The third edition's ``REPORT.md`` and figures (``results/VERDICT_RULES.md``), from its data alone.

Each cell's primary family (every method against ``none``) gives its outcomes and the verdict of the main
hypothesis; its controls validate it; the paper's two figures are restaged beside their population answers.
Nothing but the results directory is read (no clock, no checkout), and every random draw (the figures'
bands) has its own seed, so the same data give the same bytes wherever the report is written.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dqn_transfer.analysis.equivalence import POWER_TARGET, Contrast, Outcome, contrast, outcomes
from dqn_transfer.analysis.plots import curves_figure, dot_whisker_figure, errorbar_figure
from dqn_transfer.analysis.stats import Estimate
from dqn_transfer.experiments.cell_runs import CONTROL, CellMaps, by_cell, read_maps
from dqn_transfer.experiments.edition import (
    MAPS_FILE,
    MAPS_TABLE,
    REPEAT_FILE,
    STAGES_FILE,
    TUNING_DIR,
    Cell,
    Edition,
)
from dqn_transfer.experiments.equivalence_claims import (
    CONTROLS,
    FINAL_SHARE,
    HORIZON,
    SESOI,
    Comparison,
    Verdict,
    auc_value,
    failed_controls,
    family,
    final_from,
    final_value,
    room,
    verdict,
)
from dqn_transfer.experiments.hierarchical_claims import MODE_PAIRS, MODES
from dqn_transfer.experiments.power import differences_by_map
from dqn_transfer.experiments.raw_data import (
    DATA_DIR,
    DATA_SOURCE,
    DataError,
    RunData,
    carry_file,
    data_digest,
    read_evidence,
    read_experiment,
)
from dqn_transfer.experiments.render import COLORS, LEARNER_NAMES
from dqn_transfer.experiments.report_parts import include, opening, p_text, records_table
from dqn_transfer.experiments.scoring import group, learner, mode
from dqn_transfer.experiments.tuning import FIGURE_FILE, TABLE_FILE

TARGET_MINUTES = 120  # the bound on the whole study
MODE_TABLE = [  # the header of a table of mode differences
    "| difference | mean [95% CI] | maps | p difference | p equivalence | outcome |",
    "|---|---|---:|---:|---:|---|",
]


@dataclass(frozen=True)
class CellResult:
    """One cell's answer: its primary family on both outcomes, its controls, its room, its verdict."""

    cell: Cell
    description: str
    maps: int
    seeds: int
    primary: list[Comparison]  # normalised AUC, each method - none, Holm within
    secondary: list[Comparison]  # final score, the same comparisons
    controls: list[Comparison]
    against_sham: list[Comparison]  # each method - sham, when a control failed
    room: Contrast
    verdict: Verdict
    failed: list[str]


def describe_cell(run: RunData) -> str:
    """A cell's learner, game and team, from one of its runs' config."""
    name, env = LEARNER_NAMES.get(learner(run), learner(run)), run.config["env"]
    if env.get("factory") is not None:
        return f"{name}, Level-Based Foraging, {env['kwargs']['players']} players"
    return f"{name}, treasure hunt {env['size']}x{env['size']}, {env['num_agents']} agents"


def cell_result(cell: Cell, runs: dict[str, list[RunData]]) -> CellResult:
    """The registered analysis of one cell's runs (a condition's runs by its name)."""
    if CONTROL not in runs:
        raise DataError(f"cell {cell.name} has no runs of {CONTROL}")
    primary_names = [c for c in runs if c != CONTROL and c not in CONTROLS]
    controls = family(runs, [c for c in CONTROLS if c in runs], auc_value)
    failed = failed_controls(controls)
    against_sham = family(runs, primary_names, auc_value, against="sham") if "sham" in runs and failed else []
    primary = family(runs, primary_names, auc_value)
    return CellResult(
        cell,
        describe_cell(runs[CONTROL][0]),
        len({r.map_seed for r in runs[CONTROL]}),
        len({r.seed for r in runs[CONTROL]}),
        primary,
        family(runs, primary_names, final_value),
        controls,
        against_sham,
        room(runs[CONTROL], auc_value),
        verdict(primary),
        failed,
    )


# ------------------------------------------------------------------------------------------- text


def interval(c: Contrast, digits: int = 3) -> str:
    return f"{c.mean:+.{digits}f} [{c.low:+.{digits}f}, {c.high:+.{digits}f}]"


def comparison_rows(comparisons: Sequence[Comparison], against: str) -> list[str]:
    rows = [
        "| comparison | mean difference [95% CI] | 90% CI (TOST) | maps | p difference (Holm) | "
        "p equivalence (Holm) | outcome |",
        "|---|---|---|---:|---:|---:|---|",
    ]
    for c in comparisons:
        x = c.contrast
        rows.append(
            f"| {c.name} − {against} | {interval(x)} | [{x.low_tost:+.3f}, {x.high_tost:+.3f}] | {x.n_maps} | "
            f"{p_text(x.p_difference)} ({p_text(c.p_difference)}) | {p_text(x.p_equivalence)} "
            f"({p_text(c.p_equivalence)}) | {c.outcome.value} |"
        )
    return rows + [""]


def verdict_text(result: CellResult) -> str:
    if not result.failed:
        return result.verdict.value
    return f"{result.verdict.value}, NOT VALIDATED ({', '.join(result.failed)} failed)"


def power_text(maps: CellMaps | None) -> str:
    """Each primary comparison's power at the SESOI on the cell's maps (from the pilot's variance)."""
    if maps is None:
        return "(no power rule recorded)"
    powers = ", ".join(f"{c.condition} {c.power_at_maps:.0%}" for c in maps.comparisons)
    below = [c.condition for c in maps.comparisons if c.power_at_maps < POWER_TARGET]
    return f"Power at the SESOI on these maps, from the pilot's variance: {powers}; " + (
        f"below {POWER_TARGET:.0%}: {', '.join(below)}." if below else f"all at least {POWER_TARGET:.0%}."
    )


def cell_section(result: CellResult, figure: str, maps: CellMaps | None) -> list[str]:
    """A cell's section: its verdict, families, controls and figure."""
    name = result.cell.name
    lines = [
        f"## Cell {name}: {result.description}",
        "",
        f"{result.maps} maps × {result.seeds} seeds per condition. Room (oracle − `none`, normalised AUC): "
        f"{interval(result.room)}. {power_text(maps)}",
        "",
        f"**Main hypothesis: {verdict_text(result)}.**",
        "",
        "Primary family, normalised AUC (each method against `none`, paired by map and seed, seeds averaged "
        f"within a map, a t interval over maps; SESOI {SESOI:g}; both tests Holm-adjusted within the family):",
        "",
        *comparison_rows(result.primary, CONTROL),
        "Controls (a family of two): `sham` must come out equivalent, `warm` better.",
        "",
        *comparison_rows(result.controls, CONTROL),
    ]
    if result.against_sham:
        lines += [
            "A control failed: each method against `sham` (secondary):",
            "",
            *comparison_rows(result.against_sham, "sham"),
        ]
    lines += [
        f"Secondary, the final score (the mean normalised score of each run's last {FINAL_SHARE:.0%} of steps), "
        "no verdict:",
        "",
        *comparison_rows(result.secondary, CONTROL),
        f"![cell {name}]({figure})",
        "",
    ]
    return lines


def cells_figure(results: Sequence[CellResult], path: Path, watermark: str | None) -> None:
    """Every cell's comparisons against ``none`` with their 95% intervals, the equivalence band shaded."""
    panels = []
    for result in results:
        points = {c.name: _estimate(c.contrast) for c in (*result.primary, *result.controls)}
        panels.append((f"{result.cell.name}: {result.description}", {"X − none": points}))
    dot_whisker_figure(
        path,
        panels,
        "difference in normalised AUC (95% CI)",
        f"Each method against none; the shaded band is ±{SESOI:g} (the SESOI)",
        watermark=watermark,
        reference=0.0,
        shaded=(-SESOI, SESOI),
    )


def _estimate(c: Contrast) -> Estimate:
    return Estimate(c.mean, c.low, c.high, c.n_maps)


# ------------------------------------------------------------------------------------------- the paper's figures


def by_mode(runs: Sequence[RunData]) -> dict[str, list[RunData]]:
    """Runs by team mode, in the modes' order (competitive, cooperative, deliberative)."""
    found = group(runs, mode)
    return {name: found[name] for name in MODES if name in found}


def mode_family(runs: Sequence[RunData], pairs: Sequence[tuple[str, str]]) -> list[str]:
    """Mode differences in normalised AUC over a population's maps, Holm within ``pairs``, as table rows."""
    modes = by_mode(runs)
    present = [(x, y) for x, y in pairs if x in modes and y in modes]
    contrasts = [contrast(differences_by_map(modes[x], modes[y], auc_value), SESOI) for x, y in present]
    return [
        f"| {x} − {y} | {interval(c)} | {c.n_maps} | {p_text(c.p_difference)} | {p_text(c.p_equivalence)} | {o.value} |"
        for (x, y), c, o in zip(present, contrasts, outcomes(contrasts))
    ]


def final_team_return(run: RunData) -> float:
    """A run's mean team return over the last 20% of its steps."""
    steps, values = run.curve()
    return float(values[steps >= final_from(run)].mean())


def t_estimate(values: Sequence[float]) -> Estimate:
    """Mean and 95% t interval of independent values (a single value has none)."""
    if len(values) < 2:
        return Estimate(float(np.mean(values)), float("nan"), float("nan"), len(values))
    c = contrast([[v] for v in values], SESOI)
    return Estimate(c.mean, c.low, c.high, c.n_maps)


def figure1_section(paper: Sequence[RunData], maps: Sequence[RunData], out: Path, watermark: str | None) -> list[str]:
    if not (paper or maps):
        return []
    lines = ["## The paper's Figure 1, restaged: cooperative against competitive with one treasure", ""]
    if paper:
        curves = {name: [r.curve() for r in mode_runs] for name, mode_runs in by_mode(paper).items()}
        curves_figure(
            out / "figure1.png",
            [("team_return", curves)],
            "Figure 1 restaged: the simple map\none chest, one trap, 2 agents, SARSA",
            np.random.default_rng([3, 1]),
            COLORS.get,
            watermark=watermark,
        )
        seeds = len({r.seed for r in paper})
        lines += [
            f"The paper's way: greedy team return against training steps on its simple map, {seeds} seeds a mode.",
            "",
            "![Figure 1](figure1.png)",
            "",
        ]
    if maps:
        lines += [
            f"Population answer: {len({r.map_seed for r in maps})} generated maps of the same kind × "
            f"{len({r.seed for r in maps})} seeds, the difference in normalised AUC (paired by map and seed; "
            f"outcome against ±{SESOI:g}):",
            "",
            *MODE_TABLE,
            *mode_family(maps, [("cooperative", "competitive")]),
            "",
        ]
    return lines


def figure2_section(paper: Sequence[RunData], maps: Sequence[RunData], out: Path, watermark: str | None) -> list[str]:
    if not (paper or maps):
        return []
    lines = ["## The paper's Figure 2, restaged: three modes as the team grows", ""]
    sizes = sorted({int(r.config["env"]["num_agents"]) for r in (*paper, *maps)})
    if paper:
        series: dict[str, dict[int, Estimate]] = {}
        for name, mode_runs in by_mode(paper).items():
            series[name] = {
                size: t_estimate([final_team_return(r) for r in mode_runs if r.config["env"]["num_agents"] == size])
                for size in sizes
                if any(r.config["env"]["num_agents"] == size for r in mode_runs)
            }
        errorbar_figure(
            out / "figure2.png",
            [("final team return (last 20% of steps)", series)],
            "agents (as many chests and traps)",
            "Figure 2 restaged: the complex map, SARSA\nmean over seeds, 95% t interval",
            COLORS.get,
            watermark,
        )
        lines += [
            "The paper's way: final greedy team return against team size on its complex map, "
            f"{len({r.seed for r in paper})} seeds per mode and size.",
            "",
            "![Figure 2](figure2.png)",
            "",
        ]
    if maps:
        lines += [
            f"Population answer: {len({r.map_seed for r in maps})} generated maps × {len({r.seed for r in maps})} "
            "seeds per size; mode differences in normalised AUC, Holm within each size:",
            "",
        ]
        for size in sizes:
            runs = [r for r in maps if r.config["env"]["num_agents"] == size]
            if runs:
                lines += [f"{size} agents:", "", *MODE_TABLE, *mode_family(runs, MODE_PAIRS), ""]  # Holm within a size
    return lines


# ------------------------------------------------------------------------------------------- the report


def stages_table(results: Path) -> list[str]:
    """Each stage's wall time (its attempts summed), from ``stages.json``."""
    try:
        stages: dict[str, list[float]] = json.loads((results / STAGES_FILE).read_text())
    except (OSError, ValueError):
        return ["(no stage times recorded)", ""]
    return [*times_table(stages), "", *repeat_times(results)]


def times_table(stages: dict[str, list[float]]) -> list[str]:
    rows = ["| stage | attempts | wall time |", "|---|---:|---:|"]
    rows += [f"| {stage} | {len(times)} | {sum(times) / 60:.1f} min |" for stage, times in stages.items()]
    total = sum(sum(times) for times in stages.values()) / 60
    return [*rows, f"| all | | {total:.1f} min (target {TARGET_MINUTES} min) |"]


def repeat_times(results: Path) -> list[str]:
    """The stage times of the study run again from scratch elsewhere (``repeat.json``), and whether its run
    records are these, by their digest."""
    try:
        repeat: dict[str, Any] = json.loads((results / REPEAT_FILE).read_text())
    except (OSError, ValueError):  # as stages.json: no record, no line
        return []
    same = repeat["data_sha256"] == data_digest(results / DATA_DIR)
    made = "; ".join(", ".join(repeat[key]) for key in ("commit", "date", "machine"))
    records = "are these, byte for byte" if same else "**differ** from these"
    return [
        f"Every stage run again from scratch into another directory ({made}):",
        f"its run records {records} (sha256 of `data/*.jsonl`).",
        "",
        *times_table(repeat["stages"]),
        "",
    ]


def text_list(items: Sequence[str] | None, none: str) -> list[str]:
    return [*(f"- {item}" for item in items), ""] if items else [none, ""]


def write_report(edition: Edition, results: Path, out: Path) -> Path:
    """``OUT/REPORT.md`` and its figures from ``RESULTS/data/`` and the tuning, maps and stage times beside it."""
    evidence = read_evidence(results)
    runs = {name: read_experiment(evidence.data, name) for name in edition.experiments}
    if not any(runs.values()):
        raise DataError(f"{evidence.data} holds no data of {', '.join(edition.experiments)}")
    cells_runs: dict[str, dict[str, list[RunData]]] = {}
    for cell in edition.cells:
        cells_runs.update(by_cell(runs[cell.experiment]))
    cell_results = [cell_result(c, cells_runs[c.name]) for c in edition.cells if c.name in cells_runs]
    out.mkdir(parents=True, exist_ok=True)  # after the data are read: bad input leaves no directory behind
    text: dict[str, Any] = edition.report
    body: list[str] = []
    if cell_results:
        cells_figure(cell_results, out / "cells.png", evidence.watermark)
    maps = read_maps(results / MAPS_FILE) if (results / MAPS_FILE).is_file() else {}
    for result in cell_results:
        body += cell_section(result, "cells.png", maps.get(result.cell.name))
    body += figure1_section(runs["figure1"], runs["figure1_maps"], out, evidence.watermark)
    body += figure2_section(runs["figure2"], runs["figure2_maps"], out, evidence.watermark)
    missing = [name for name in edition.experiments if not runs[name]]
    header = [
        *opening(edition, evidence, missing),
        f"Data: {DATA_SOURCE}. Verdict rules: `{edition.rules}`, registered at "
        f"{evidence.manifest.get('rules_commit', '?')} before any of these runs (`REGISTRATION.md`). A normalised "
        "score puts the map's uniformly random team at 0 and the oracle at 1; the primary outcome is its mean over "
        f"a run's evaluations (normalised AUC) over the horizon of {HORIZON:,} steps.",
        "",
        *records_table(evidence),
        "| cell | learner, game, team | maps × seeds | room | verdict |",
        "|---|---|---|---|---|",
        *[
            f"| {r.cell.name} | {r.description} | {r.maps} × {r.seeds} | {interval(r.room)} | **{verdict_text(r)}** |"
            for r in cell_results
        ],
        "",
        *replication_lines(cell_results, text.get("replication")),
        "## Stage times",
        "",
        *stages_table(results),
        "## Methods",
        "",
        *text_list([f"`{k}` — {v}" for k, v in (text.get("methods") or {}).items()], "(no methods described)"),
        "## Deviations from the registered rules",
        "",
        *text_list(text.get("deviations"), "None."),
        "## Not run",
        "",
        *text_list(text.get("not_run"), "Nothing."),
        "## Earlier editions",
        "",
        *text_list(text.get("editions"), "None."),
        "## Tuning (stage 2)",
        "",
    ]
    for game in edition.tuning:
        table, figure = Path(TUNING_DIR) / game.name / TABLE_FILE, Path(TUNING_DIR) / game.name / FIGURE_FILE
        header += [f"### {game.name}", "", *include(results / table)]
        if carry_file(results, out, figure):
            header += [f"![tuning {game.name}]({figure.as_posix()})", ""]
    header += ["## Maps per cell (stage 3)", "", *include(results / MAPS_TABLE)]
    report = out / "REPORT.md"
    report.write_text("\n".join(header + body))
    return report


def better_methods(result: CellResult) -> set[str]:
    return {c.name for c in result.primary if c.outcome is Outcome.better}


def replication_lines(results: Sequence[CellResult], pair: Sequence[str] | None) -> list[str]:
    """REPLICATED if the second cell's verdict and better methods are the first's (``pair``: S4, L2)."""
    found = {r.cell.name: r for r in results}
    if not pair or any(name not in found for name in pair):
        return []
    first, second = (found[name] for name in pair)
    same = first.verdict is second.verdict and better_methods(first) == better_methods(second)
    return [f"Replication of {pair[0]} on {pair[1]}: **{'REPLICATED' if same else 'NOT REPLICATED'}**.", ""]
