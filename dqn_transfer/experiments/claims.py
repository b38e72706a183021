"""The study's questions, one report section each, with a verdict by the rules of ``results/VERDICT_RULES.md``.

- the main hypothesis: a group that exchanges knowledge learns better than the same group without
  (experiments ``hypothesis`` and ``hypothesis_shared``);
- claim 1, one treasure: cooperation gives no advantage over competition (``claim1``);
- claim 2, as the team grows: deliberative > cooperative > competitive (``claim2``);
- claim 3, starting from a trained agent speeds up learning (``transfer``), and a curriculum from a small
  map to a large one (``curriculum``, exploratory).

Each section reads its runs' raw data (:mod:`~dqn_transfer.experiments.raw_data`), never run
directories. A run's **score** is its mean greedy-evaluation team return over training (the area under
its learning curve divided by its steps: how well the team does while it learns), as a fraction of its
map's optimal team return where the map has one (every agent taking its own chest by a shortest path),
so maps of different sizes share a scale. Runs of two conditions with the same (map seed, seed) share
their map, initial values and exploration noise: differences are paired by that unit. rliable's IQM and
probability of improvement are stratified by map. Each section names ONE primary comparison, whose
verdict the summary reports; everything else is exploratory. All sections draw from one generator in
a fixed order, so the same data always give the same digits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

from dqn_transfer.analysis.plots import curves_figure, errorbar_figure, profile_figure
from dqn_transfer.analysis.stats import Estimate, estimate, improvement_probability, iqm, mean_intervals
from dqn_transfer.analysis.transfer_metrics import asymptotic_performance, mean_over_training, time_to_threshold
from dqn_transfer.enums import Algorithm, Mode
from dqn_transfer.experiments.raw_data import RunData

PRIMARY_LEARNER = Algorithm.sarsa.value  # the study's own learner; Double DQN is run beside it, exploratory
CLAIM1_MARGIN = 5.0  # return units (5% of a treasure's reward): a smaller cooperative advantage is negligible
THRESHOLD = 0.8  # time to threshold: steps until the score curve first reaches 80% of the optimal return
FINAL_TAIL = 0.2  # final performance: the mean of the last 20% of a run's evaluations
SLOPE_RESAMPLES = 10_000
COMPETITIVE, COOPERATIVE, DELIBERATIVE = (m.value for m in Mode)
NO_EXCHANGE, SHARED_NETWORK = "none", "shared network"
SCRATCH, MATCHED = "scratch", "scratch_matched"
TRANSFER_CONDITIONS = ("same_map", "same_map_one", "other_map", "team_member")
COLORS = {
    COMPETITIVE: "tab:red",
    COOPERATIVE: "tab:blue",
    DELIBERATIVE: "tab:green",
    NO_EXCHANGE: "tab:gray",
    "best": "tab:purple",
    "shared_replay": "tab:orange",
    SHARED_NETWORK: "tab:brown",
    SCRATCH: "tab:gray",
    MATCHED: "black",
    "same_map": "tab:purple",
    "same_map_one": "tab:pink",
    "other_map": "tab:olive",
    "team_member": "tab:cyan",
    "room_scratch": "tab:gray",
    "room_curriculum": "tab:purple",
    "sarsa": "tab:blue",
    "double_dqn": "tab:red",
}
SUPPORTED, NOT_SUPPORTED, CONTRADICTED, INCONCLUSIVE = "SUPPORTED", "NOT SUPPORTED", "CONTRADICTED", "INCONCLUSIVE"
SCORE_LABEL = "team return / the map's optimal return"  # the score's axis label (plots.METRIC_LABELS["score"])


@dataclass
class Context:
    """What every section shares: where figures go, the generator, and the smoke-run mark."""

    out: Path
    rng: np.random.Generator
    watermark: str | None = None


@dataclass
class Section:
    """One question's part of the report: its summary row and its Markdown."""

    question: str
    primary: str
    result: str
    verdict: str
    markdown: str
    figures: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------------ runs and scores


def learner(run: RunData) -> str:
    return run.config["agent"]["algorithm"]


def mode(run: RunData) -> str:
    return run.config["env"]["mode"]


def team_size(run: RunData) -> int:
    return int(run.config["env"]["num_agents"])


def score(run: RunData) -> float:
    return mean_over_training(run.score_curve())


def on_total_steps(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The score curve against total env steps: a warm-started run's starts after the steps spent on what it
    started from (its source's pretraining, a curriculum's stages)."""
    steps, values = run.score_curve()
    return steps + run.steps_before, values


def raw_score(run: RunData) -> float:
    """Mean evaluation team return over training, in return units."""
    return mean_over_training(run.curve())


def final_score(run: RunData) -> float:
    return asymptotic_performance(run.score_curve(), FINAL_TAIL)


def group(runs: Sequence[RunData], key: Callable[[RunData], Any]) -> dict[Any, list[RunData]]:
    """Runs by ``key``, each group in unit order (so groups of the same units line up)."""
    groups: dict[Any, list[RunData]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    return {k: sorted(v, key=lambda r: r.unit) for k, v in groups.items()}


def paired(a: Sequence[RunData], b: Sequence[RunData], fn: Callable[[RunData], float]) -> np.ndarray:
    """``fn(a) - fn(b)`` for every unit both conditions ran."""
    by_unit = {r.unit: fn(r) for r in b}
    return np.array([fn(r) - by_unit[r.unit] for r in a if r.unit in by_unit])


def by_map(runs: Sequence[RunData], fn: Callable[[RunData], float]) -> np.ndarray:
    """``[runs per map, maps]``, the layout rliable stratifies by; one column when the maps hold unequal
    numbers of runs."""
    maps = group(runs, lambda r: r.map_seed)
    counts = {len(v) for v in maps.values()}
    if len(counts) != 1:
        return np.array([[fn(r)] for r in runs])
    return np.array([[fn(r) for r in maps[m]] for m in sorted(maps)]).T


def improvement(
    a: Sequence[RunData], b: Sequence[RunData], fn: Callable[[RunData], float], rng: np.random.Generator
) -> Estimate:
    """P(a run of ``a`` scores higher than a run of ``b`` on the same map), rliable's, stratified by map;
    over the maps both conditions ran, so that the two score tables' columns are the same maps."""
    shared = {r.map_seed for r in a} & {r.map_seed for r in b}
    a, b = ([r for r in runs if r.map_seed in shared] for runs in (a, b))
    return improvement_probability(by_map(a, fn), by_map(b, fn), rng)


def poi_verdict(p: Estimate) -> str:
    if not p.has_ci:
        return INCONCLUSIVE
    return SUPPORTED if p.low > 0.5 else CONTRADICTED if p.high < 0.5 else NOT_SUPPORTED


def fmt(e: Estimate, digits: int = 3) -> str:
    if not math.isfinite(e.mean):
        return "n/a"
    if not e.has_ci:
        return f"{e.mean:.{digits}g} [no interval]"
    if e.low == e.high:
        return f"{e.mean:.{digits}g} [no spread]"
    return f"{e.mean:.{digits}g} [{e.low:.{digits}g}, {e.high:.{digits}g}]"


def interval_text(values: np.ndarray, rng: np.random.Generator) -> tuple[str, dict[str, Estimate]]:
    """A paired difference's mean with its t, BCa and percentile 95% intervals, as one cell."""
    intervals = mean_intervals(values, rng)
    t = intervals["t"]
    if not t.has_ci:
        return fmt(t), intervals
    return (
        f"{t.mean:+.3g}, t [{t.low:+.3g}, {t.high:+.3g}], BCa [{intervals['bca'].low:+.3g}, "
        f"{intervals['bca'].high:+.3g}], pct [{intervals['percentile'].low:+.3g}, "
        f"{intervals['percentile'].high:+.3g}] (n={t.n})"
    ), intervals


def t_text(intervals: dict[str, Estimate]) -> str:
    """The paired difference's mean with its t interval: the summary's short form."""
    t = intervals["t"]
    return f"{t.mean:+.3g}, t [{t.low:+.3g}, {t.high:+.3g}]" if t.has_ci else fmt(t)


def describe(runs: Sequence[RunData]) -> str:
    """How much evidence: steps per run, evaluations, maps and seeds."""

    def values(key: Callable[[dict], Any]) -> str:
        return "/".join(f"{v:,}" for v in sorted({key(r.config) for r in runs}))

    maps = len({r.map_seed for r in runs})
    seeds = len({r.seed for r in runs})
    return (
        f"{values(lambda c: c['total_steps'])} env steps per run, a greedy evaluation of "
        f"{values(lambda c: c['eval_episodes'])} episodes every {values(lambda c: c['eval_every'])} steps; "
        f"{maps} map{'s' if maps > 1 else ''} x {seeds} seed{'s' if seeds > 1 else ''} per condition"
    )


def _color(label: str) -> str | None:
    return COLORS.get(label.split(" (")[0].split(", ")[-1])


def _learners(runs: Sequence[RunData]) -> list[str]:
    """The learners present, the primary one first."""
    present = {learner(r) for r in runs}
    return sorted(present, key=lambda a: (a != PRIMARY_LEARNER, a))


# ------------------------------------------------------------------------------------ main hypothesis


def exchange_condition(run: RunData) -> str:
    if run.config["agent"].get("share_parameters"):
        return SHARED_NETWORK
    return run.config["transfer"]["exchange"]


def section_hypothesis(runs: Sequence[RunData], ctx: Context) -> Section:
    question = "Main hypothesis: a group that exchanges knowledge learns better than the same group without"
    primary = f"{PRIMARY_LEARNER}, cooperative: P(exchange=best > none) in score"
    cells = group(runs, lambda r: (learner(r), mode(r), exchange_condition(r)))
    rows = [
        "| learner | mode | condition | score, mean [95% CI] | final score IQM [95% CI] | "
        "paired difference from none (t, BCa, percentile) | P(condition > none) [95% CI] |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    panels, profiles = [], []
    verdict, result = INCONCLUSIVE, "no runs of the primary comparison"
    for algorithm in _learners(runs):
        for team_mode in (COOPERATIVE, DELIBERATIVE):
            conditions = {
                c: cells[(algorithm, team_mode, c)]
                for c in (NO_EXCHANGE, "best", "shared_replay", SHARED_NETWORK)
                if (algorithm, team_mode, c) in cells
            }
            if NO_EXCHANGE not in conditions:
                continue
            control = conditions[NO_EXCHANGE]
            for condition, members in conditions.items():
                cell_score = fmt(estimate([score(r) for r in members], ctx.rng))
                final = fmt(iqm(by_map(members, final_score), ctx.rng))
                if condition == NO_EXCHANGE:
                    rows.append(f"| {algorithm} | {team_mode} | {condition} | {cell_score} | {final} | — | — |")
                    continue
                diff, intervals = interval_text(paired(members, control, score), ctx.rng)
                p = improvement(members, control, score, ctx.rng)
                rows.append(f"| {algorithm} | {team_mode} | {condition} | {cell_score} | {final} | {diff} | {fmt(p)} |")
                if (algorithm, team_mode, condition) == (PRIMARY_LEARNER, COOPERATIVE, "best"):
                    verdict, result = poi_verdict(p), f"P = {fmt(p)}; score difference {t_text(intervals)}"
            panels.append(
                (
                    "score",
                    {
                        f"{algorithm}, {team_mode}, {c}": [r.score_curve() for r in members]
                        for c, members in conditions.items()
                    },
                )
            )
            profiles.append(
                (f"{algorithm}, {team_mode}", {c: by_map(members, final_score) for c, members in conditions.items()})
            )
    figures = []
    if panels:
        figures.append(
            curves_figure(
                ctx.out / "hypothesis.png",
                panels,
                "Knowledge exchange in a team of 4",
                ctx.rng,
                color_of=_color,
                watermark=ctx.watermark,
            ).name
        )
        figures.append(
            profile_figure(
                ctx.out / "hypothesis_profiles.png",
                profiles,
                "Performance profiles of the final score (rliable)",
                ctx.rng,
                color_of=_color,
                watermark=ctx.watermark,
            ).name
        )
    md = [
        f"Setting: teams of 4 on claim 2's 8x8 maps, cooperative and deliberative, at the same env-step budget; "
        f"{describe(runs)}. `best`: every 20 episodes the best agent's values are soft-copied (weight 0.5) into the "
        "others; `shared_replay`: every agent also learns from its teammates' transitions; `shared network`: one "
        "Double DQN network for the team (parameter sharing, the standard multi-agent baseline).",
        "",
        *(f"![{f}]({f})\n" for f in figures),
        *rows,
        "",
        f"Primary comparison: {primary}. Verdict: **{verdict}** ({result}).",
        "Everything else in the table is exploratory.",
    ]
    return Section(question, primary, result, verdict, "\n".join(md), figures)


# ------------------------------------------------------------------------------------ claim 1


def _after_clear(members: Sequence[RunData], metric: str, digits: str) -> str:
    """A metric's final value averaged over runs; n/a for runs made before it was recorded."""
    if not all(metric in r.metrics for r in members):
        return "n/a"
    return f"{np.mean([asymptotic_performance(r.curve(metric), FINAL_TAIL) for r in members]):{digits}}"


def section_claim1(runs: Sequence[RunData], ctx: Context) -> Section:
    question = "Claim 1: with one treasure, cooperation gives no advantage over competition"
    primary = (
        f"{PRIMARY_LEARNER}: paired difference cooperative - competitive in mean team return over training, "
        f"t interval, against a margin of +{CLAIM1_MARGIN:g}"
    )
    cells = group(runs, lambda r: (learner(r), mode(r)))
    rows = [
        "| learner | competitive | cooperative | cooperative - competitive (t, BCa, percentile) | "
        "P(cooperative > competitive) | after the chest is taken: episodes with an agent still playing, "
        "comp / coop | its return after it, comp / coop |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    verdict, result, panels = INCONCLUSIVE, "no runs of the primary comparison", []
    for algorithm in _learners(runs):
        comp, coop = cells.get((algorithm, COMPETITIVE)), cells.get((algorithm, COOPERATIVE))
        if not comp or not coop:
            continue
        diff, intervals = interval_text(paired(coop, comp, raw_score), ctx.rng)
        p = improvement(coop, comp, raw_score, ctx.rng)
        after = [_after_clear(g, "after_clear_rate", ".2f") for g in (comp, coop)]
        after_return = [_after_clear(g, "return_after_clear", ".1f") for g in (comp, coop)]
        rows.append(
            f"| {algorithm} | {fmt(estimate([raw_score(r) for r in comp], ctx.rng))} | "
            f"{fmt(estimate([raw_score(r) for r in coop], ctx.rng))} | {diff} | {fmt(p)} | "
            f"{' / '.join(after)} | {' / '.join(after_return)} |"
        )
        panels.append(
            (
                "team_return",
                {f"{algorithm}, {m}": [r.curve() for r in g] for m, g in ((COMPETITIVE, comp), (COOPERATIVE, coop))},
            )
        )
        if algorithm == PRIMARY_LEARNER:
            t = intervals["t"]
            if not t.has_ci:
                verdict = INCONCLUSIVE
            elif t.high < CLAIM1_MARGIN:
                verdict = SUPPORTED
            elif t.low > CLAIM1_MARGIN:
                verdict = NOT_SUPPORTED
            else:
                verdict = INCONCLUSIVE
            result = f"difference {t_text(intervals)} return units"
    figures = []
    if panels:
        figures.append(
            curves_figure(
                ctx.out / "claim1.png",
                panels,
                "One treasure: competitive vs cooperative",
                ctx.rng,
                color_of=_color,
                watermark=ctx.watermark,
            ).name
        )
    md = [
        f"Setting: 2 agents, 1 chest, 1 trap on generated 6x6 maps; {describe(runs)}.",
        "",
        *(f"![{f}]({f})\n" for f in figures),
        *rows,
        "",
        "Does the announcement have any decision value here? Once the only chest is taken nothing is left to "
        "find: every further move costs 1 wherever the agent goes, and the episode ends only at the horizon or "
        "in a trap (-100). Knowing that the chest is gone therefore cannot raise the team's return; it could only "
        "change where the remaining agent wanders. The last two columns measure how often that situation arises "
        f"in the final {FINAL_TAIL:.0%} of evaluations and what it costs in each mode. By the game's rules, "
        "claim 1 holds by construction on one-chest maps, whatever the learner.",
        "",
        f"Primary comparison: {primary}. Rule: SUPPORTED if the interval lies below +{CLAIM1_MARGIN:g}, NOT "
        f"SUPPORTED if it lies above, INCONCLUSIVE otherwise. Verdict: **{verdict}** ({result}).",
        "Everything else in the table is exploratory.",
    ]
    return Section(question, primary, result, verdict, "\n".join(md), figures)


# ------------------------------------------------------------------------------------ claim 2


def slope(diffs: dict[int, np.ndarray], rng: np.random.Generator) -> tuple[float, Estimate, Estimate]:
    """``(slope, bootstrap, t)`` of a paired difference against team size m: the least-squares slope of
    the per-m mean differences, with a percentile interval resampling the units within each m, and the
    classic t interval of the regression of every unit's difference on m."""
    sizes = np.array(sorted(diffs), dtype=np.float64)
    means = np.array([diffs[int(m)].mean() for m in sizes])
    centred = sizes - sizes.mean()
    point = float(centred @ means / (centred @ centred))
    resampled = np.stack(
        [
            d[rng.integers(0, d.size, size=(SLOPE_RESAMPLES, d.size))].mean(axis=1)
            for d in (diffs[int(m)] for m in sizes)
        ],
        axis=1,
    )  # [resamples, sizes]
    slopes = (resampled - resampled.mean(axis=1, keepdims=True)) @ centred / (centred @ centred)
    low, high = np.quantile(slopes, [0.025, 0.975])
    x = np.concatenate([np.full(diffs[int(m)].size, m) for m in sizes])
    y = np.concatenate([diffs[int(m)] for m in sizes])
    fit = scipy.stats.linregress(x, y)
    half = scipy.stats.t.ppf(0.975, x.size - 2) * fit.stderr
    n = int(x.size)
    return (
        point,
        Estimate(point, float(low), float(high), n),
        Estimate(float(fit.slope), fit.slope - half, fit.slope + half, n),
    )


def trend_verdict(slopes: Sequence[Estimate]) -> str:
    if not all(s.has_ci for s in slopes):
        return INCONCLUSIVE
    if all(s.low > 0 for s in slopes):
        return SUPPORTED
    return CONTRADICTED if any(s.high < 0 for s in slopes) else NOT_SUPPORTED


def section_claim2(runs: Sequence[RunData], ctx: Context) -> Section:
    question = "Claim 2: as the team grows, deliberative > cooperative > competitive"
    primary = (
        f"{PRIMARY_LEARNER}: slopes over team size of the paired differences deliberative - cooperative "
        "and cooperative - competitive in score, bootstrap CIs"
    )
    cells = group(runs, lambda r: (learner(r), team_size(r), mode(r)))
    sizes = sorted({m for _, m, _ in cells})
    rows = [
        "| learner | m | competitive | cooperative | deliberative | coop - comp | delib - coop |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    final_rows = [
        f"| learner | m | final score (last {FINAL_TAIL:.0%} of evaluations), IQM [95% CI]: competitive | "
        "cooperative | deliberative |",
        "|---|---:|---:|---:|---:|",
    ]
    trend_rows = [
        "| learner | difference | slope per extra agent, bootstrap [95% CI] | t [95% CI] | verdict |",
        "|---|---|---:|---:|---|",
    ]
    level_panels, trend_series = [], {"deliberative - cooperative": {}, "cooperative - competitive": {}}
    verdict, result = INCONCLUSIVE, "no runs of the primary comparison"
    for algorithm in _learners(runs):
        level = {m_: {} for m_ in (COMPETITIVE, COOPERATIVE, DELIBERATIVE)}
        diffs: dict[str, dict[int, np.ndarray]] = {"deliberative - cooperative": {}, "cooperative - competitive": {}}
        for m in sizes:
            modes = {team_mode: cells.get((algorithm, m, team_mode)) for team_mode in level}
            if not all(modes.values()):
                continue
            for team_mode, members in modes.items():
                level[team_mode][m] = estimate([score(r) for r in members], ctx.rng)
            diffs["cooperative - competitive"][m] = paired(modes[COOPERATIVE], modes[COMPETITIVE], score)
            diffs["deliberative - cooperative"][m] = paired(modes[DELIBERATIVE], modes[COOPERATIVE], score)
            cc, dc = (
                interval_text(diffs[k][m], ctx.rng)[0]
                for k in ("cooperative - competitive", "deliberative - cooperative")
            )
            rows.append(f"| {algorithm} | {m} | " + " | ".join(fmt(level[t][m]) for t in level) + f" | {cc} | {dc} |")
            final_rows.append(
                f"| {algorithm} | {m} | "
                + " | ".join(fmt(iqm(by_map(modes[t], final_score), ctx.rng)) for t in level)
                + " |"
            )
        if len(diffs["cooperative - competitive"]) < 2:
            continue
        level_panels.append((f"{algorithm}: {SCORE_LABEL}", level))
        slopes = []
        for name, by_size in diffs.items():
            _, boot, t = slope(by_size, ctx.rng)
            slopes.append(boot)
            trend_series[name][algorithm] = {m: estimate(d, ctx.rng) for m, d in by_size.items()}
            trend_rows.append(f"| {algorithm} | {name} | {fmt(boot)} | {fmt(t)} | |")
        learner_verdict = trend_verdict(slopes)
        trend_rows[-1] = trend_rows[-1][:-2] + f" {learner_verdict} |"
        largest = max(diffs["cooperative - competitive"])
        for a, b in ((DELIBERATIVE, COOPERATIVE), (COOPERATIVE, COMPETITIVE)):
            p = improvement(cells[(algorithm, largest, a)], cells[(algorithm, largest, b)], score, ctx.rng)
            trend_rows.append(f"| {algorithm} | P({a} > {b}) at m = {largest} | {fmt(p)} | | exploratory |")
        if algorithm == PRIMARY_LEARNER:
            verdict = learner_verdict
            result = "; ".join(f"{name} slope {fmt(s)}" for name, s in zip(diffs, slopes))
    figures = []
    if level_panels:
        figures.append(
            errorbar_figure(
                ctx.out / "claim2.png",
                level_panels,
                "team size m (agents = chests = traps; the map grows with m)",
                "Score by team size and mode (mean, 95% bootstrap CI)",
                color_of=_color,
                watermark=ctx.watermark,
            ).name
        )
        figures.append(
            errorbar_figure(
                ctx.out / "claim2_trend.png",
                [(f"{name} (score)", series) for name, series in trend_series.items()],
                "team size m",
                "Gaps between modes by team size (paired by map and seed)",
                color_of=_color,
                watermark=ctx.watermark,
                zero_line=True,
            ).name
        )
    md = [
        f"Setting: teams of m = {', '.join(map(str, sizes))} agents with as many chests and traps on generated maps "
        f"that grow with the team (6x6, 7x7, 8x8, 10x10); {describe(runs)}. Score = {SCORE_LABEL}, averaged over "
        "training.",
        "",
        *(f"![{f}]({f})\n" for f in figures),
        *rows,
        "",
        *trend_rows,
        "",
        "Every run has the same env-step budget, so larger teams on larger maps end further from convergence "
        "(final scores below): a gap's trend over m mixes the modes' effect with how far learning got.",
        "",
        *final_rows,
        "",
        f"Primary comparison: {primary}. Rule: SUPPORTED if both slopes' intervals lie above 0, CONTRADICTED if "
        f"either lies below 0, NOT SUPPORTED otherwise. Verdict: **{verdict}** ({result}). The same rule applied "
        "to Double DQN is exploratory.",
    ]
    return Section(question, primary, result, verdict, "\n".join(md), figures)


# ------------------------------------------------------------------------------------ claim 3: transfer


def _infer_condition(config: dict[str, Any]) -> str:
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


def section_transfer(runs: Sequence[RunData], ctx: Context) -> Section:
    question = "Claim 3: starting from a trained agent speeds up learning"
    primary = f"{PRIMARY_LEARNER}: P(same_map > scratch_matched) in score"
    cells = group(runs, lambda r: (learner(r), _infer_condition(r.config)))
    rows = [
        "| learner | condition | source cost (steps) | score | jumpstart (first evaluation) | "
        "score difference (t, BCa, percentile) | P(condition > baseline) | reached 80% | P(sooner) | "
        "break-even reuses |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    verdict, result, panels, total_panels = INCONCLUSIVE, "no runs of the primary comparison", [], []
    for algorithm in _learners(runs):
        baseline = cells.get((algorithm, MATCHED))
        if not baseline:
            continue
        order = [SCRATCH, *TRANSFER_CONDITIONS]
        rows.append(
            f"| {algorithm} | {MATCHED} (the baseline) | 0 | {fmt(estimate([score(r) for r in baseline], ctx.rng))} "
            f"| — | — | — | {sum(not math.isnan(_time_to_threshold(r)) for r in baseline)}/{len(baseline)} | — | — |"
        )
        for condition in order:
            members = cells.get((algorithm, condition))
            if not members:
                continue
            cost = int(np.mean([r.steps_before for r in members]))
            jump = estimate(paired(members, baseline, lambda r: r.score_curve()[1][0]), ctx.rng)
            diff, intervals = interval_text(paired(members, baseline, score), ctx.rng)
            p = improvement(members, baseline, score, ctx.rng)
            sooner = improvement(members, baseline, _sooner, ctx.rng)
            saved = float(np.mean(paired(baseline, members, _budgeted_time)))
            reuses = "—" if cost == 0 else (f"{cost / saved:.1f}" if saved > 0 else "never")
            reached = sum(not math.isnan(_time_to_threshold(r)) for r in members)
            rows.append(
                f"| {algorithm} | {condition} | {cost:,} | {fmt(estimate([score(r) for r in members], ctx.rng))} "
                f"| {fmt(jump)} | {diff} | {fmt(p)} | {reached}/{len(members)} | {fmt(sooner)} | {reuses} |"
            )
            if (algorithm, condition) == (PRIMARY_LEARNER, "same_map"):
                verdict, result = poi_verdict(p), f"P = {fmt(p)}; score difference {t_text(intervals)}"
        groups = {c: cells[(algorithm, c)] for c in [MATCHED, *order] if (algorithm, c) in cells}
        panels.append(("score", {f"{algorithm}, {c}": [r.score_curve() for r in g] for c, g in groups.items()}))
        total_panels.append(("score", {f"{algorithm}, {c}": [on_total_steps(r) for r in g] for c, g in groups.items()}))
    figures = []
    if panels:
        figures.append(
            curves_figure(
                ctx.out / "transfer.png",
                panels,
                "Transfer: target-task steps",
                ctx.rng,
                color_of=_color,
                watermark=ctx.watermark,
            ).name
        )
        figures.append(
            curves_figure(
                ctx.out / "transfer_total_steps.png",
                total_panels,
                "Transfer: total steps (each run starts after its source's pretraining)",
                ctx.rng,
                color_of=_color,
                watermark=ctx.watermark,
                xlabel="environment steps, the source's pretraining included",
                marks=[(c, "sources pretrained") for c in sorted({r.steps_before for r in runs} - {0})],
            ).name
        )
    md = [
        f"Setting: teams of 2 on claim 2's 6x6 maps; {describe(runs)}. The baseline is `{MATCHED}`: random start "
        "with the transferred agents' exploration (epsilon from 0.3), so exploration alone cannot pass for "
        "transfer; `scratch` (epsilon from 1.0) is shown against it too. Jumpstart and score differences are "
        "paired by map and seed. Time to threshold: steps until the score first reaches "
        f"{THRESHOLD:.0%} of the optimal return; P(sooner) counts a run that never gets there as slower than "
        "every run that does. Break-even reuses: the source's cost divided by the mean steps to threshold it "
        "saves a target run (a run that never gets there counted at its budget): how many runs must start from "
        "one source before it has paid for itself.",
        "",
        *(f"![{f}]({f})\n" for f in figures),
        *rows,
        "",
        f"Primary comparison: {primary}. Rule: SUPPORTED if the interval lies above 0.5, CONTRADICTED if below, "
        f"NOT SUPPORTED otherwise. Verdict: **{verdict}** ({result}). Everything else is exploratory.",
    ]
    return Section(question, primary, result, verdict, "\n".join(md), figures)


# ------------------------------------------------------------------------------------ curriculum


def _mean_between(run: RunData, start: float, end: float) -> float:
    steps, values = on_total_steps(run)
    kept = (steps >= start) & (steps <= end)
    return mean_over_training((steps[kept], values[kept]))


def section_curriculum(runs: Sequence[RunData], ctx: Context) -> Section:
    question = "Curriculum: a small map first beats the large map from scratch at the same total steps"
    primary = "none (exploratory: not in the verdict rules)"
    cells = group(
        runs,
        lambda r: (learner(r), "room_curriculum" if r.config.get("curriculum", {}).get("stages") else "room_scratch"),
    )
    rows = [
        "| learner | steps before (room) | score at the curriculum's start: curriculum - scratch | score over the "
        "shared steps: curriculum - scratch (t, BCa, percentile) | final score (equal budget): curriculum / "
        "scratch | P(curriculum > scratch), final |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    panels, results = [], []
    for algorithm in _learners(runs):
        curriculum, scratch = cells.get((algorithm, "room_curriculum")), cells.get((algorithm, "room_scratch"))
        if not curriculum or not scratch:
            continue
        start = max(r.steps_before for r in curriculum)
        end = min(float(on_total_steps(r)[0][-1]) for r in curriculum + scratch)
        at_start = {r.unit: float(np.interp(start, *on_total_steps(r))) for r in scratch}
        jump = estimate([on_total_steps(r)[1][0] - at_start[r.unit] for r in curriculum if r.unit in at_start], ctx.rng)
        diff = (
            interval_text(paired(curriculum, scratch, partial(_mean_between, start=start, end=end)), ctx.rng)[0]
            if end > start
            else "no shared steps (unequal budgets)"
        )
        p = improvement(curriculum, scratch, final_score, ctx.rng)
        finals = " / ".join(fmt(estimate([final_score(r) for r in g], ctx.rng)) for g in (curriculum, scratch))
        rows.append(f"| {algorithm} | {start:,} | {fmt(jump)} | {diff} | {finals} | {fmt(p)} |")
        results.append(f"{algorithm}: P = {fmt(p)}")
        panels.append(
            (
                "score",
                {
                    f"{algorithm}, {c}": [on_total_steps(r) for r in g]
                    for c, g in (("room_scratch", scratch), ("room_curriculum", curriculum))
                },
            )
        )
    figures = []
    if panels:
        figures.append(
            curves_figure(
                ctx.out / "curriculum.png",
                panels,
                "Curriculum vs scratch at equal total steps",
                ctx.rng,
                color_of=_color,
                watermark=ctx.watermark,
                xlabel="environment steps, the room stage's included",
                marks=[(c, "room stage ends") for c in sorted({r.steps_before for r in runs} - {0})],
            ).name
        )
    md = [
        f"Setting: an 8x8 map with 2 chests, 2 traps and 2 agents; the curriculum first trains one agent on the "
        f"5x5 room it contains (at (1, 1)), then both agents start from it; {describe(runs)} (the curriculum's "
        "own steps exclude the room's). Both conditions spend the same total env steps.",
        "",
        *(f"![{f}]({f})\n" for f in figures),
        *rows,
        "",
        "This comparison was added after the main rules and is exploratory: no verdict.",
    ]
    return Section(question, primary, "; ".join(results) or "no runs", "EXPLORATORY", "\n".join(md), figures)


# (section function, the experiments whose data it reads), in report order
SECTIONS = {
    "hypothesis": (section_hypothesis, ("hypothesis", "hypothesis_shared")),
    "claim1": (section_claim1, ("claim1",)),
    "claim2": (section_claim2, ("claim2",)),
    "transfer": (section_transfer, ("transfer",)),
    "curriculum": (section_curriculum, ("curriculum",)),
}
