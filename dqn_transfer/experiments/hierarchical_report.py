"""The registered hierarchical analysis's ``REPORT.md`` and figures (the second edition's), from its data alone.

Each question has its own seeded random stream (:func:`stream`) and nothing else is read (no clock, no
checkout), so the same data give the same bytes.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from pathlib import Path

import numpy as np

from dqn_transfer.analysis.hierarchical import MeanDifference
from dqn_transfer.analysis.plots import dot_whisker_figure, errorbar_figure
from dqn_transfer.analysis.stats import Estimate
from dqn_transfer.experiments import render
from dqn_transfer.experiments.edition import BUDGETS_TABLE, TUNING_DIR, Edition
from dqn_transfer.experiments.hierarchical_claims import (
    ALPHA,
    CLAIM1_MARGIN,
    FAILURE_BELOW,
    MODE_PAIRS,
    MODES,
    SMALLEST_EFFECT,
    Claim1Result,
    Claim2Result,
    Claim3Result,
    Difference,
    HypothesisResult,
    Summary,
    claim1,
    claim2,
    claim3,
    hypothesis,
    mode,
    replicated,
)
from dqn_transfer.experiments.raw_data import (
    DATA_SOURCE,
    DataError,
    carry_file,
    read_evidence,
    read_experiment,
)
from dqn_transfer.experiments.render import COLORS
from dqn_transfer.experiments.report_parts import include, opening, p_text, records_table

TUNING_TABLE = Path(TUNING_DIR) / "tuning.md"
TUNING_FIGURE = Path(TUNING_DIR) / "tuning_sensitivity.png"
GREEDY = "greedy, "  # the label prefix of a mode's greedy team in claim 2's figure


fmt = partial(render.fmt, mark_no_spread=False)


def signed(e: Estimate, digits: int = 3) -> str:
    if not e.has_ci:
        return f"{e.mean:+.{digits}g} [no interval]"
    return f"{e.mean:+.{digits}g} [{e.low:+.{digits}g}, {e.high:+.{digits}g}]"


def difference_text(d: Difference) -> str:
    holm = "" if d.holm_p is None else f", Holm {p_text(d.holm_p)}"
    small = (
        " (below the smallest effect of interest)"
        if d.significant and abs(d.difference.estimate.mean) < SMALLEST_EFFECT
        else ""
    )
    return f"{signed(d.difference.estimate)}, p {p_text(d.difference.p_value)}{holm}{small}"


def slope_text(s: MeanDifference) -> str:
    return f"{signed(s.estimate)}, p {p_text(s.p_value)}"


def summary_cells(s: Summary) -> str:
    failure = "—" if s.failure is None else fmt(s.failure, 2)
    return f"{fmt(s.mean)} | {fmt(s.iqm)} | {failure}"


def _family(title: str, table: list[str], verdict: str) -> list[str]:
    """A family's table under its title, then its verdict's line."""
    return [title, "", *table, "", verdict, ""]


def _family_table(members: Sequence[Difference], against: str, metric: str) -> list[str]:
    lines = [
        f"| method | {metric}: X − {against} [95% CI], p (Holm) | P(X > {against}) [95% CI] "
        f"| power at d = {SMALLEST_EFFECT:g} |",
        "|---|---:|---:|---:|",
    ]
    for d in members:
        lines.append(f"| {d.label} | {difference_text(d)} | {fmt(d.improvement)} | {d.power:.2f} |")
    return lines


# ------------------------------------------------------------------------------------------- sections


def hypothesis_section(result: HypothesisResult, title: str, figure: str, note: str | None = None) -> list[str]:
    lines = [
        f"## {title}",
        "",
        *([note, ""] if note else []),
        "Budgets (each learner x mode, from the pilot): "
        + ", ".join(f"{learner} {m} {b:,}" for (learner, m), b in result.budgets.items())
        + " env steps.",
        "",
        f"![{figure}]({figure})",
        "",
        "| learner | mode | method | runs | final score, mean [95% CI] | IQM | failure rate (final score < "
        f"{FAILURE_BELOW:g}) | final score at B/2 | AUC score | X − none, final score (p) | X − none at B/2 | "
        "P(X > none) |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in result.rows:
        vs = "—" if row.against_none is None else difference_text(row.against_none)
        vs_half = "—" if row.against_none_half is None else difference_text(row.against_none_half)
        poi = "—" if row.against_none is None else fmt(row.against_none.improvement)
        lines.append(
            f"| {row.learner} | {row.mode} | {row.method} | {row.final.runs} | {summary_cells(row.final)} | "
            f"{fmt(row.half.mean)} | {fmt(row.auc.mean)} | {vs} | {vs_half} | {poi} |"
        )
    lines += [
        "",
        *_family(
            f"**Primary family** (SARSA, {result.primary_mode}, final score at B, Holm over the three):",
            _family_table(result.primary, "none", "final score"),
            f"Verdict: **{result.verdict}**.",
        ),
        *_family(
            f"**Secondary family** (Double DQN, {result.primary_mode}, Holm over the three):",
            _family_table(result.secondary, "none", "final score"),
            f"Secondary verdict: **{result.secondary_verdict}**. Everything else in the table is exploratory.",
        ),
        *_negative_control(result),
    ]
    return lines


def _negative_control(result: HypothesisResult) -> list[str]:
    """The negative control's line: ``best`` − none in the families' mode, expected not to be positive; and the
    room ``none`` leaves below the optimum, beside the smallest effect of interest."""
    rows = {(r.learner, r.method): r for r in result.rows if r.mode == result.primary_mode}
    lines = []
    for learner in dict.fromkeys(r.learner for r in result.rows):
        control, none = rows.get((learner, "best")), rows.get((learner, "none"))
        if control is None or control.against_none is None or none is None:
            continue
        expected = "as expected" if control.against_none.sign <= 0 else "**not as expected**: copying helps too"
        room = 1.0 - none.final.mean.mean
        lines.append(
            f"- **Negative control** ({learner}): `best` − none {difference_text(control.against_none)}. Expected "
            f"≤ 0; {expected}. `none` ends at {fmt(none.final.mean)}, {room:.3f} below the optimum"
            + (f": less than the smallest effect of interest ({SMALLEST_EFFECT:g})." if room < SMALLEST_EFFECT else ".")
        )
    return [*lines, ""] if lines else []


def hypothesis_figure(result: HypothesisResult, path: Path, watermark: str | None) -> None:
    panels: dict[str, dict[str, dict[str, Estimate]]] = {}  # learner -> mode -> method -> final score
    for row in result.rows:
        panels.setdefault(row.learner, {}).setdefault(row.mode, {})[row.method] = row.final.mean
    dot_whisker_figure(
        path,
        list(panels.items()),
        "final score (fraction of the optimal team return), mean and 95% CI over maps",
        "Knowledge exchange, teams of 4",
        COLORS.get,
        watermark,
        reference=1.0,
    )


def claim1_section(result: Claim1Result) -> list[str]:
    d = result.difference
    return [
        "## Claim 1: with one treasure, cooperation gives no advantage over competition",
        "",
        "The exact part is value iteration on the joint game (`docs/claim1_exact.md`): on every map tested, each "
        "mode's own-observation team reaches the full-information optimum, so the optimal values of the modes "
        "are equal. The learning part:",
        "",
        "| mode | runs | final team return, mean [95% CI] | IQM |",
        "|---|---:|---:|---:|",
        f"| competitive | {result.competitive.runs} | {fmt(result.competitive.mean)} | {fmt(result.competitive.iqm)} |",
        f"| cooperative | {result.cooperative.runs} | {fmt(result.cooperative.mean)} | {fmt(result.cooperative.iqm)} |",
        "",
        f"Primary: cooperative − competitive in final team return, {difference_text(d)}; P(coop > comp) "
        f"{fmt(d.improvement)}; against the margin +{CLAIM1_MARGIN:g}. Verdict: **{result.verdict}**.",
        "",
    ]


def claim2_section(result: Claim2Result, figure: str) -> list[str]:
    lines = [
        "## Claim 2: as the team grows, deliberative > cooperative > competitive",
        "",
        f"![{figure}]({figure})",
        "",
        "| contention | m | competitive | cooperative | deliberative | delib − coop | coop − comp |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for cell in result.cells:
        modes = " | ".join(fmt(cell.modes[name].mean) for name in MODES)
        diffs = " | ".join(slope_text(cell.differences[pair]) for pair in MODE_PAIRS)
        lines.append(f"| {cell.contention} | {cell.m} | {modes} | {diffs} |")
    lines += [
        "",
        "Beside them, the greedy nearest-chest team's score on the same maps (`docs/bounds.md`; the oracle "
        "scores 1 by definition):",
        "",
        "| contention | m | greedy, competitive | cooperative | deliberative |",
        "|---|---:|---:|---:|---:|",
    ]
    for cell in result.cells:
        floors = " | ".join(fmt(result.floors[(cell.contention, cell.m, name)]) for name in MODES)
        lines.append(f"| {cell.contention} | {cell.m} | {floors} |")
    lines += ["", "| contention | slope over m of | per agent [95% CI], p |", "|---|---|---:|"]
    for (level, pair), slope in result.slopes.items():
        lines.append(f"| {level} | {pair[0]} − {pair[1]} | {slope_text(slope)} |")
    if result.contention_effects:
        lines += ["", "| m | high − low contention, of | [95% CI], p |", "|---:|---|---:|"]
        for (m, pair), effect in result.contention_effects.items():
            lines.append(f"| {m} | {pair[0]} − {pair[1]} | {slope_text(effect)} |")
    lines += ["", f"Primary (high contention, both slopes above 0): **{result.verdict}**.", ""]
    return lines


def claim2_figure(result: Claim2Result, path: Path, watermark: str | None) -> None:
    panels: dict[str, dict[str, dict[int, Estimate]]] = {}  # panel title -> series -> m -> final score
    for cell in result.cells:
        series = panels.setdefault(f"final score, {cell.contention} contention", {})
        for name, summary in cell.modes.items():
            series.setdefault(name, {})[cell.m] = summary.mean
            series.setdefault(f"{GREEDY}{name}", {})[cell.m] = result.floors[(cell.contention, cell.m, name)]

    def color(label: str) -> str | None:  # a mode's greedy team in the mode's colour
        return COLORS.get(label.removeprefix(GREEDY))

    errorbar_figure(
        path, list(panels.items()), "agents = chests = traps (10x10 maps)", "Growing the team", color, watermark
    )


def claim3_section(result: Claim3Result) -> list[str]:
    lines = [
        "## Claim 3: starting from trained agents speeds up learning",
        "",
        "| learner | condition | runs | AUC score | final score | X − scratch_matched, AUC (p) | "
        "at equal total steps, final score (p) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in result.rows:
        vs = "—" if row.against_control is None else difference_text(row.against_control)
        total = "—" if row.at_total_steps is None else difference_text(row.at_total_steps)
        lines.append(
            f"| {row.learner} | {row.condition} | {row.auc.runs} | {fmt(row.auc.mean)} | {fmt(row.final.mean)} | "
            f"{vs} | {total} |"
        )
    lines += [
        "",
        *_family(
            "**Primary family** (SARSA, AUC score over the target's own steps, Holm over the two):",
            _family_table(result.primary, "scratch_matched", "AUC score"),
            f"Verdict: **{result.verdict}**.",
        ),
    ]
    return lines


# ------------------------------------------------------------------------------------------- the report


def stream(edition: Edition, question: str) -> np.random.Generator:
    """A question's own random stream, seeded by its experiment's place in the edition's experiments: its digits
    do not change when another question's data arrive."""
    return np.random.default_rng([0, edition.experiments.index(question)])


def write_report(edition: Edition, results: Path, out: Path) -> Path:
    """``OUT/REPORT.md`` and its figures from ``RESULTS/data/`` and the budgets and tuning beside it."""
    evidence = read_evidence(results)
    runs = {name: read_experiment(evidence.data, name) for name in edition.experiments}
    if not any(runs.values()):
        raise DataError(f"{evidence.data} holds no data of {', '.join(edition.experiments)}")
    out.mkdir(parents=True, exist_ok=True)  # after the data are read: bad input leaves no directory behind
    summary: list[tuple[str, str]] = []
    body: list[str] = []
    treasure = None
    if runs["hypothesis"]:
        treasure = hypothesis(runs["hypothesis"], stream(edition, "hypothesis"))
        hypothesis_figure(treasure, out / "hypothesis.png", evidence.watermark)
        body += hypothesis_section(
            treasure, "Main hypothesis: a group that exchanges knowledge learns better", "hypothesis.png"
        )
        summary.append(("Main hypothesis (SARSA, cooperative)", treasure.verdict))
        summary.append(("Main hypothesis, secondary (Double DQN, cooperative)", treasure.secondary_verdict))
    if runs["lbf_hypothesis"]:
        lbf = hypothesis(
            runs["lbf_hypothesis"], stream(edition, "lbf_hypothesis"), primary_mode=mode(runs["lbf_hypothesis"][0])
        )
        hypothesis_figure(lbf, out / "lbf_hypothesis.png", evidence.watermark)
        body += hypothesis_section(
            lbf,
            "Replication on Level-Based Foraging",
            "lbf_hypothesis.png",
            f"Level-Based Foraging has no team modes: its runs carry the default `mode={lbf.primary_mode}`, which "
            "the game ignores. Its score is the game's own normalised team return (1 = all food loaded).",
        )
        summary.append(("Main hypothesis on Level-Based Foraging", lbf.verdict))
        if treasure is not None:
            summary.append(("Replication", replicated(treasure, lbf)))
    if runs["claim1"]:
        result1 = claim1(runs["claim1"], stream(edition, "claim1"))
        body += claim1_section(result1)
        summary.append(("Claim 1", result1.verdict))
    if runs["claim2"]:
        result2 = claim2(runs["claim2"], stream(edition, "claim2"))
        claim2_figure(result2, out / "claim2.png", evidence.watermark)
        body += claim2_section(result2, "claim2.png")
        summary.append(("Claim 2", result2.verdict))
    if runs["transfer"]:  # claim 3's control (scratch_matched) is among them: transfer_aware's wait for it
        result3 = claim3(runs["transfer"] + runs["transfer_aware"], stream(edition, "transfer"))
        body += claim3_section(result3)
        summary.append(("Claim 3", result3.verdict))
    missing = [name for name in edition.experiments if not runs[name]]
    header = [
        *opening(edition, evidence, missing, "; their questions have no verdict yet."),
        *(
            ["> Claim 3 compares `transfer_aware`'s runs with the control among `transfer`'s: it waits for them.", ""]
            if runs["transfer_aware"] and not runs["transfer"]
            else []
        ),
        f"Data: {DATA_SOURCE}. Verdict rules: `{edition.rules}`, tagged `{edition.rules_tag}` at "
        f"{evidence.manifest.get('rules_commit', '?')}, before any of these runs. Intervals are 95% "
        "hierarchical-bootstrap intervals over maps (maps, then runs within maps); p-values are two-sided "
        f"bootstrap p; a family's are Holm-adjusted at {ALPHA:g}.",
        "",
        *records_table(evidence),
        "| question | verdict |",
        "|---|---|",
        *[f"| {question} | **{verdict}** |" for question, verdict in summary],
        "",
        "## Tuning (stage 2)",
        "",
        *include(results / TUNING_TABLE),
        *([f"![tuning]({TUNING_FIGURE.as_posix()})", ""] if carry_file(results, out, TUNING_FIGURE) else []),
        "## Budgets (stage 3)",
        "",
        *include(results / BUDGETS_TABLE),
    ]
    report = out / "REPORT.md"
    report.write_text("\n".join(header + body))
    return report
