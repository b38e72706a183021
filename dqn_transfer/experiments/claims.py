"""The first edition's questions, each computed from its runs' raw data into a typed result (:mod:`results`).

Each question names ONE primary comparison, whose verdict follows ``results/v1/VERDICT_RULES.md``; everything
else is exploratory. The sections draw from one generator in a fixed order (each section's numbers, then its
figures, drawn by :mod:`render`), so the same data always give the same digits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np

from dqn_transfer.analysis.stats import Estimate, estimate, iqm
from dqn_transfer.analysis.transfer_metrics import asymptotic_performance, mean_over_training, time_to_threshold
from dqn_transfer.enums import Mode
from dqn_transfer.experiments.raw_data import RunData
from dqn_transfer.experiments.results import (
    CONTRADICTED,
    EXPLORATORY,
    INCONCLUSIVE,
    NOT_SUPPORTED,
    SUPPORTED,
    Claim1,
    Claim2,
    Curriculum,
    CurriculumRow,
    ExchangeRow,
    Hypothesis,
    Intervals,
    ModesRow,
    Panel,
    Primary,
    Result,
    Series,
    SizeRow,
    Transfer,
    TransferRow,
    Trend,
)
from dqn_transfer.experiments.scoring import (
    FINAL_TAIL,
    PRIMARY_LEARNER,
    by_map,
    final_score,
    group,
    improvement,
    learner,
    learners,
    mode,
    on_total_steps,
    paired,
    raw_score,
    score,
    slope,
    team_size,
)
from dqn_transfer.experiments.settings import Evidence, Game, values

CLAIM1_MARGIN = 5.0  # return units (5% of a treasure's reward): a smaller cooperative advantage is negligible
THRESHOLD = 0.8  # time to threshold: steps until the score curve first reaches 80% of the optimal return
COMPETITIVE, COOPERATIVE, DELIBERATIVE = (m.value for m in Mode)
NO_EXCHANGE, SHARED_NETWORK = "none", "shared network"
EXCHANGES = (NO_EXCHANGE, "best", "shared_replay", SHARED_NETWORK)
SCRATCH, MATCHED = "scratch", "scratch_matched"
TRANSFER_CONDITIONS = ("same_map", "same_map_one", "other_map", "team_member")
ROOM_SCRATCH, ROOM_CURRICULUM = "room_scratch", "room_curriculum"
GAPS = {
    "deliberative - cooperative": (DELIBERATIVE, COOPERATIVE),
    "cooperative - competitive": (COOPERATIVE, COMPETITIVE),
}


def poi_verdict(p: Estimate) -> str:
    if not p.has_ci:
        return INCONCLUSIVE
    return SUPPORTED if p.low > 0.5 else CONTRADICTED if p.high < 0.5 else NOT_SUPPORTED


def margin_verdict(t: Estimate, margin: float) -> str:
    """Claim 1: no advantage when the difference's interval lies below the margin."""
    if not t.has_ci:
        return INCONCLUSIVE
    return SUPPORTED if t.high < margin else NOT_SUPPORTED if t.low > margin else INCONCLUSIVE


def trend_verdict(slopes: Sequence[Estimate]) -> str:
    if not all(s.has_ci for s in slopes):
        return INCONCLUSIVE
    if all(s.low > 0 for s in slopes):
        return SUPPORTED
    return CONTRADICTED if any(s.high < 0 for s in slopes) else NOT_SUPPORTED


def _panel(metric: str, cells: dict[tuple[str, str], list[RunData]], curve: Callable[[RunData], Any]) -> Panel:
    return Panel(metric, [Series(f"{a}, {c}", c, [curve(r) for r in runs]) for (a, c), runs in cells.items()])


# ------------------------------------------------------------------------------------ main hypothesis


def exchange_condition(run: RunData) -> str:
    if run.config["agent"].get("share_parameters"):
        return SHARED_NETWORK
    return run.config["transfer"]["exchange"]


def hypothesis(runs: Sequence[RunData], rng: np.random.Generator) -> Hypothesis:
    cells = group(runs, lambda r: (learner(r), mode(r), exchange_condition(r)))
    rows, panels, profiles = [], [], []
    p_primary, diff_primary = None, None
    for algorithm in learners(runs):
        for team_mode in (COOPERATIVE, DELIBERATIVE):
            conditions = {c: cells[(algorithm, team_mode, c)] for c in EXCHANGES if (algorithm, team_mode, c) in cells}
            if NO_EXCHANGE not in conditions:
                continue
            control = conditions[NO_EXCHANGE]
            for condition, members in conditions.items():
                cell = estimate([score(r) for r in members], rng)
                final = iqm(by_map(members, final_score), rng)
                if condition == NO_EXCHANGE:
                    rows.append(ExchangeRow(algorithm, team_mode, condition, cell, final, None, None))
                    continue
                diff = Intervals.of(paired(members, control, score), rng)
                p = improvement(members, control, score, rng)
                rows.append(ExchangeRow(algorithm, team_mode, condition, cell, final, diff, p))
                if (algorithm, team_mode, condition) == (PRIMARY_LEARNER, COOPERATIVE, "best"):
                    p_primary, diff_primary = p, diff
            panels.append(
                _panel(
                    "score", {(f"{algorithm}, {team_mode}", c): g for c, g in conditions.items()}, RunData.score_curve
                )
            )
            profiles.append((algorithm, team_mode, {c: by_map(g, final_score) for c, g in conditions.items()}))
    best = [r for r in runs if exchange_condition(r) == "best"]
    return Hypothesis(
        Primary(
            "Main hypothesis: a group that exchanges knowledge learns better than the same group without",
            f"{PRIMARY_LEARNER}, cooperative: P(exchange=best > none) in score",
            poi_verdict(p_primary) if p_primary else INCONCLUSIVE,
        ),
        Evidence.of(runs),
        Game.of(runs),
        tuple(m for m in (COOPERATIVE, DELIBERATIVE) if any(mode(r) == m for r in runs)),
        values(best, lambda c: c["transfer"]["exchange_every"]),
        values(best, lambda c: c["transfer"]["exchange_tau"]),
        tuple(learners([r for r in runs if exchange_condition(r) == SHARED_NETWORK])),
        rows,
        p_primary,
        diff_primary,
        panels,
        profiles,
    )


# ------------------------------------------------------------------------------------ claim 1


def _final_mean(members: Sequence[RunData], metric: str) -> float | None:
    """A metric's final value averaged over runs; None for runs made before it was recorded."""
    if not all(metric in r.metrics for r in members):
        return None
    return float(np.mean([asymptotic_performance(r.curve(metric), FINAL_TAIL) for r in members]))


def claim1(runs: Sequence[RunData], rng: np.random.Generator) -> Claim1:
    cells = group(runs, lambda r: (learner(r), mode(r)))
    rows, panels, diff_primary = [], [], None
    for algorithm in learners(runs):
        comp, coop = cells.get((algorithm, COMPETITIVE)), cells.get((algorithm, COOPERATIVE))
        if not comp or not coop:
            continue
        diff = Intervals.of(paired(coop, comp, raw_score), rng)
        p = improvement(coop, comp, raw_score, rng)
        levels = [estimate([raw_score(r) for r in g], rng) for g in (comp, coop)]
        after = (_final_mean(comp, "after_clear_rate"), _final_mean(coop, "after_clear_rate"))
        after_return = (_final_mean(comp, "return_after_clear"), _final_mean(coop, "return_after_clear"))
        rows.append(ModesRow(algorithm, levels[0], levels[1], diff, p, after, after_return))
        panels.append(
            _panel("team_return", {(algorithm, COMPETITIVE): comp, (algorithm, COOPERATIVE): coop}, RunData.curve)
        )
        if algorithm == PRIMARY_LEARNER:
            diff_primary = diff
    return Claim1(
        Primary(
            "Claim 1: with one treasure, cooperation gives no advantage over competition",
            f"{PRIMARY_LEARNER}: paired difference cooperative - competitive in mean team return over training, "
            f"t interval, against a margin of +{CLAIM1_MARGIN:g}",
            margin_verdict(diff_primary.t, CLAIM1_MARGIN) if diff_primary else INCONCLUSIVE,
        ),
        Evidence.of(runs),
        Game.of(runs),
        CLAIM1_MARGIN,
        FINAL_TAIL,
        rows,
        diff_primary,
        panels,
    )


# ------------------------------------------------------------------------------------ claim 2


def _trend(
    algorithm: str,
    levels: dict[str, dict[int, Estimate]],
    gaps: dict[str, dict[int, np.ndarray]],
    cells: dict[Any, list[RunData]],
    rng: np.random.Generator,
) -> Trend:
    """The learner's gaps' slopes over team size and the rule's verdict, then P at the largest team."""
    slopes, series = {}, {}
    for name, by_size in gaps.items():
        _, boot, t = slope(by_size, rng)
        slopes[name] = (boot, t)
        series[name] = {m: estimate(d, rng) for m, d in by_size.items()}
    largest = max(gaps["cooperative - competitive"])
    improvements = [
        (a, b, improvement(cells[(algorithm, largest, a)], cells[(algorithm, largest, b)], score, rng))
        for a, b in GAPS.values()
    ]
    verdict = trend_verdict([boot for boot, _ in slopes.values()])
    return Trend(algorithm, slopes, verdict, largest, improvements, levels, series)


def claim2(runs: Sequence[RunData], rng: np.random.Generator) -> Claim2:
    cells = group(runs, lambda r: (learner(r), team_size(r), mode(r)))
    sizes = sorted({m for _, m, _ in cells})
    rows, trends = [], []
    for algorithm in learners(runs):
        levels: dict[str, dict[int, Estimate]] = {m_: {} for m_ in (COMPETITIVE, COOPERATIVE, DELIBERATIVE)}
        gaps: dict[str, dict[int, np.ndarray]] = {name: {} for name in GAPS}
        for m in sizes:
            if not all((algorithm, m, team_mode) in cells for team_mode in levels):
                continue
            modes: dict[str, list[RunData]] = {team_mode: cells[(algorithm, m, team_mode)] for team_mode in levels}
            for team_mode, members in modes.items():
                levels[team_mode][m] = estimate([score(r) for r in members], rng)
            for name, (a, b) in GAPS.items():
                gaps[name][m] = paired(modes[a], modes[b], score)
            coop_comp, delib_coop = (Intervals.of(gaps[k][m], rng) for k in reversed(GAPS))
            finals = {t: iqm(by_map(g, final_score), rng) for t, g in modes.items()}
            rows.append(SizeRow(algorithm, m, {t: levels[t][m] for t in levels}, (coop_comp, delib_coop), finals))
        if len(gaps["cooperative - competitive"]) >= 2:
            trends.append(_trend(algorithm, levels, gaps, cells, rng))
    primary = next((t for t in trends if t.learner == PRIMARY_LEARNER), None)
    by_m = group(runs, team_size)
    return Claim2(
        Primary(
            "Claim 2: as the team grows, deliberative > cooperative > competitive",
            f"{PRIMARY_LEARNER}: slopes over team size of the paired differences deliberative - cooperative "
            "and cooperative - competitive in score, bootstrap CIs",
            primary.verdict if primary else INCONCLUSIVE,
        ),
        Evidence.of(runs),
        sizes,
        {m: values(by_m[m], lambda c: c["env"].get("size")) for m in sizes},
        all(r.config["env"].get(k) == team_size(r) for r in runs for k in ("num_treasures", "num_traps")),
        FINAL_TAIL,
        rows,
        trends,
        {name: boot for name, (boot, _) in primary.slopes.items()} if primary else None,
    )


# ------------------------------------------------------------------------------------ claim 3: transfer


def transfer_condition(config: dict[str, Any]) -> str:
    """The transfer experiment's condition of a run, from its transfer and exploration settings."""
    transfer = config["transfer"]
    if not transfer["enabled"]:
        return MATCHED if config["agent"]["eps_start"] == transfer["epsilon_start"] else SCRATCH
    if transfer.get("source_task") == "team":
        return "team_member"
    if transfer.get("source_map_shift"):
        return "other_map"
    return "same_map_one" if transfer.get("targets") else "same_map"


def _time_to_threshold(run: RunData) -> float:
    return time_to_threshold(run.score_curve(), THRESHOLD)


def _budgeted_time(run: RunData) -> float:
    """Steps to the threshold, the run's budget for a run that never got there (a lower bound)."""
    t = _time_to_threshold(run)
    return float(run.config["total_steps"]) if math.isnan(t) else t


def _sooner(run: RunData) -> float:
    t = _time_to_threshold(run)
    return -math.inf if math.isnan(t) else -t


def _reached(runs: Sequence[RunData]) -> int:
    return sum(not math.isnan(_time_to_threshold(r)) for r in runs)


def _transfer_row(algorithm: str, condition: str, members: list[RunData], baseline: list[RunData], rng) -> TransferRow:
    cost = int(np.mean([r.steps_before for r in members]))
    jump = estimate(paired(members, baseline, lambda r: r.score_curve()[1][0]), rng)
    diff = Intervals.of(paired(members, baseline, score), rng)
    p = improvement(members, baseline, score, rng)
    sooner = improvement(members, baseline, _sooner, rng)
    saved = float(np.mean(paired(baseline, members, _budgeted_time)))
    level = estimate([score(r) for r in members], rng)
    return TransferRow(algorithm, condition, cost, level, _reached(members), len(members), jump, diff, p, sooner, saved)


def transfer(runs: Sequence[RunData], rng: np.random.Generator) -> Transfer:
    cells = group(runs, lambda r: (learner(r), transfer_condition(r.config)))
    rows, panels, total_panels = [], [], []
    primary: TransferRow | None = None
    for algorithm in learners(runs):
        baseline = cells.get((algorithm, MATCHED))
        if not baseline:
            continue
        level = estimate([score(r) for r in baseline], rng)
        rows.append(TransferRow(algorithm, MATCHED, 0, level, _reached(baseline), len(baseline)))
        for condition in (SCRATCH, *TRANSFER_CONDITIONS):
            if cells.get((algorithm, condition)):
                rows.append(_transfer_row(algorithm, condition, cells[(algorithm, condition)], baseline, rng))
                if (algorithm, condition) == (PRIMARY_LEARNER, "same_map"):
                    primary = rows[-1]
        groups = {
            (algorithm, c): cells[(algorithm, c)]
            for c in (MATCHED, SCRATCH, *TRANSFER_CONDITIONS)
            if (algorithm, c) in cells
        }
        panels.append(_panel("score", groups, RunData.score_curve))
        total_panels.append(_panel("score", groups, on_total_steps))
    by_condition = group(runs, lambda r: transfer_condition(r.config))
    return Transfer(
        Primary(
            "Claim 3: starting from a trained agent speeds up learning",
            f"{PRIMARY_LEARNER}: P(same_map > scratch_matched) in score",
            poi_verdict(primary.p) if primary and primary.p else INCONCLUSIVE,
        ),
        Evidence.of(runs),
        Game.of(runs),
        MATCHED,
        values(by_condition.get(MATCHED, []), lambda c: c["agent"]["eps_start"]),
        values(by_condition.get(SCRATCH, []), lambda c: c["agent"]["eps_start"]),
        THRESHOLD,
        rows,
        primary.p if primary else None,
        primary.difference if primary else None,
        panels,
        total_panels,
        sorted({r.steps_before for r in runs} - {0}),
    )


# ------------------------------------------------------------------------------------ curriculum


def _mean_between(run: RunData, start: float, end: float) -> float:
    steps, values = on_total_steps(run)
    kept = (steps >= start) & (steps <= end)
    return mean_over_training((steps[kept], values[kept]))


def curriculum_condition(run: RunData) -> str:
    return ROOM_CURRICULUM if run.config.get("curriculum", {}).get("stages") else ROOM_SCRATCH


def _curriculum_row(algorithm: str, curriculum: list[RunData], scratch: list[RunData], rng) -> CurriculumRow:
    start = max(r.steps_before for r in curriculum)
    end = min(float(on_total_steps(r)[0][-1]) for r in curriculum + scratch)
    at_start = {r.unit: float(np.interp(start, *on_total_steps(r))) for r in scratch}
    jump = estimate([on_total_steps(r)[1][0] - at_start[r.unit] for r in curriculum if r.unit in at_start], rng)
    between = partial(_mean_between, start=start, end=end)
    diff = Intervals.of(paired(curriculum, scratch, between), rng) if end > start else None
    p = improvement(curriculum, scratch, final_score, rng)
    finals = (estimate([final_score(r) for r in curriculum], rng), estimate([final_score(r) for r in scratch], rng))
    return CurriculumRow(algorithm, start, jump, diff, finals, p)


def curriculum(runs: Sequence[RunData], rng: np.random.Generator) -> Curriculum:
    cells = group(runs, lambda r: (learner(r), curriculum_condition(r)))
    rows, panels = [], []
    for algorithm in learners(runs):
        room, scratch = cells.get((algorithm, ROOM_CURRICULUM)), cells.get((algorithm, ROOM_SCRATCH))
        if not room or not scratch:
            continue
        rows.append(_curriculum_row(algorithm, room, scratch, rng))
        panels.append(
            _panel("score", {(algorithm, ROOM_SCRATCH): scratch, (algorithm, ROOM_CURRICULUM): room}, on_total_steps)
        )
    staged = [r for r in runs if curriculum_condition(r) == ROOM_CURRICULUM]
    return Curriculum(
        Primary(
            "Curriculum: a small map first beats the large map from scratch at the same total steps",
            "none (exploratory: not in the verdict rules)",
            EXPLORATORY,
        ),
        Evidence.of(runs),
        Game.of(runs),
        Game.of(staged, lambda c: c["curriculum"]["stages"][0]["env"]),
        values(staged, lambda c: tuple(c["transfer"].get("offset") or (0, 0))),
        rows,
        panels,
        sorted({r.steps_before for r in runs} - {0}),
    )


# (what computes the section, the experiments whose data it reads), in report order
SECTIONS: dict[str, tuple[Callable[[Sequence[RunData], np.random.Generator], Result], tuple[str, ...]]] = {
    "hypothesis": (hypothesis, ("hypothesis", "hypothesis_shared")),
    "claim1": (claim1, ("claim1",)),
    "claim2": (claim2, ("claim2",)),
    "transfer": (transfer, ("transfer",)),
    "curriculum": (curriculum, ("curriculum",)),
}
