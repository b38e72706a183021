"""The one renderer: a section's typed result (:mod:`results`) to its Markdown and figures.

Every number and setting in the text comes from the result (its estimates, and the settings read from
the runs' configs); colours come from :data:`COLORS`, keyed by condition. :func:`render` draws the
section's figures with the report's generator, after its numbers were computed from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import singledispatch
from pathlib import Path

import numpy as np

from dqn_transfer.analysis.plots import curves_figure, errorbar_figure, profile_figure
from dqn_transfer.analysis.stats import Estimate
from dqn_transfer.experiments.results import (
    Claim1,
    Claim2,
    Curriculum,
    Hypothesis,
    Intervals,
    Panel,
    Result,
    Transfer,
    TransferRow,
)
from dqn_transfer.experiments.settings import Evidence, Game

COLORS = {
    "competitive": "tab:red",
    "cooperative": "tab:blue",
    "deliberative": "tab:green",
    "none": "tab:gray",
    "best": "tab:purple",
    "shared_replay": "tab:orange",
    "shared network": "tab:brown",
    "shared_id": "tab:brown",  # the tuning's name of the shared network with agent ids
    "experience": "tab:olive",
    "confidence": "tab:cyan",
    "advice": "tab:pink",
    "scratch": "tab:gray",
    "scratch_matched": "black",
    "same_map": "tab:purple",
    "same_map_one": "tab:pink",
    "other_map": "tab:olive",
    "team_member": "tab:cyan",
    "room_scratch": "tab:gray",
    "room_curriculum": "tab:purple",
    "sarsa": "tab:blue",
    "double_dqn": "tab:red",
}
LEARNER_NAMES = {"sarsa": "SARSA", "qlearning": "Q-learning", "dqn": "DQN", "double_dqn": "Double DQN"}
COUNT_WORDS = {1: "one", 2: "two", 3: "three", 4: "four"}
SCORE_LABEL = "team return / the map's optimal return"  # the score's axis label (plots.METRIC_LABELS["score"])
NO_PRIMARY = "no runs of the primary comparison"
EXPLORATORY_NOTE = "Everything else in the table is exploratory."


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


# ------------------------------------------------------------------------------------ numbers and settings


def fmt(e: Estimate, digits: int = 3, mark_no_spread: bool = True) -> str:
    """An estimate with its interval; the second edition's report prints an interval without spread as it is."""
    if not math.isfinite(e.mean):
        return "n/a"
    if not e.has_ci:
        return f"{e.mean:.{digits}g} [no interval]"
    if mark_no_spread and e.low == e.high:
        return f"{e.mean:.{digits}g} [no spread]"
    return f"{e.mean:.{digits}g} [{e.low:.{digits}g}, {e.high:.{digits}g}]"


def intervals_text(d: Intervals) -> str:
    """A paired difference's mean with its t, BCa and percentile 95% intervals, as one cell."""
    t = d.t
    if not t.has_ci:
        return fmt(t)
    return (
        f"{t_text(d)}, BCa [{d.bca.low:+.3g}, {d.bca.high:+.3g}], "
        f"pct [{d.percentile.low:+.3g}, {d.percentile.high:+.3g}] (n={t.n})"
    )


def t_text(d: Intervals) -> str:
    """The paired difference's mean with its t interval: the summary's short form."""
    t = d.t
    return f"{t.mean:+.3g}, t [{t.low:+.3g}, {t.high:+.3g}]" if t.has_ci else fmt(t)


def poi_result(p: Estimate | None, d: Intervals | None) -> str:
    return f"P = {fmt(p)}; score difference {t_text(d)}" if p and d else NO_PRIMARY


def joined(values: tuple, spec: str = "") -> str:
    return "/".join(format(v, spec) for v in values)


def plural(values: tuple[int, ...], noun: str) -> str:
    return f"{joined(values)} {noun}{'' if values == (1,) else 's'}"


def sides(values: tuple[int, ...]) -> str:
    return "/".join(f"{s}x{s}" for s in values)


def article(text: str) -> str:
    """``a`` or ``an`` before a number: an 8x8, an 11x11, a 6x6."""
    return "an" if text.startswith(("8", "11", "18")) else "a"


def describe(e: Evidence) -> str:
    """How much evidence: steps per run, evaluations, maps and seeds."""
    return (
        f"{joined(e.total_steps, ',')} env steps per run, a greedy evaluation of {joined(e.eval_episodes, ',')} "
        f"episodes every {joined(e.eval_every, ',')} steps; {e.maps} map{'s' if e.maps > 1 else ''} x {e.seeds} "
        f"seed{'s' if e.seeds > 1 else ''} per condition"
    )


def maps_text(game: Game) -> str:
    """Where the teams play: claim 2's study maps, or generated ones."""
    where = "claim 2's" if game.study_maps else "generated"
    return f"{where} {sides(game.sizes)} maps"


# ------------------------------------------------------------------------------------ figures


def _curves_figures(ctx: Context, name: str, panels: list[Panel], title: str, **kwargs) -> list[str]:
    """``curves_figure`` of the panels, each series coloured by its condition: the figure's file name, or no
    figure without panels."""
    if not panels:
        return []
    colors = {s.label: COLORS[s.condition] for p in panels for s in p.series if s.condition in COLORS}
    figure_panels = [(p.metric, {s.label: s.curves for s in p.series}) for p in panels]
    path = curves_figure(
        ctx.out / name, figure_panels, title, ctx.rng, color_of=colors.get, watermark=ctx.watermark, **kwargs
    )
    return [path.name]


def _images(figures: list[str]) -> list[str]:
    return [f"![{f}]({f})\n" for f in figures]


# ------------------------------------------------------------------------------------ the sections


@singledispatch
def render(result: Result, ctx: Context) -> Section:
    """A section's Markdown and figures (written to ``ctx.out``) from its result."""
    raise TypeError(f"no renderer for {type(result).__name__}")


@render.register
def _(r: Hypothesis, ctx: Context) -> Section:
    rows = [
        f"| {x.learner} | {x.mode} | {x.condition} | {fmt(x.score)} | {fmt(x.final)} | "
        + (f"{intervals_text(x.difference)} | {fmt(x.p)} |" if x.difference and x.p else "— | — |")
        for x in r.rows
    ]
    title = f"Knowledge exchange in a team of {joined(r.game.agents)}"
    figures = _curves_figures(ctx, "hypothesis.png", r.panels, title)
    if r.panels:
        path = profile_figure(
            ctx.out / "hypothesis_profiles.png",
            [(f"{learner}, {mode}", scores) for learner, mode, scores in r.profiles],
            "Performance profiles of the final score (rliable)",
            ctx.rng,
            color_of=COLORS.get,
            watermark=ctx.watermark,
        )
        figures.append(path.name)
    result = poi_result(r.p, r.difference)
    shared = " / ".join(LEARNER_NAMES.get(a, a) for a in r.shared_learners)
    if shared:
        shared = (
            f"; `shared network`: one {shared} network for the team (parameter sharing, the standard multi-agent "
            "baseline)"
        )
    md = [
        f"Setting: teams of {joined(r.game.agents)} on {maps_text(r.game)}, {' and '.join(r.modes)}, at the same "
        f"env-step budget; {describe(r.evidence)}. `best`: every {joined(r.exchange_every)} episodes the best "
        f"agent's values are soft-copied (weight {joined(r.exchange_tau, 'g')}) into the others; `shared_replay`: "
        f"every agent also learns from its teammates' transitions{shared}.",
        "",
        *_images(figures),
        "| learner | mode | condition | score, mean [95% CI] | final score IQM [95% CI] | "
        "paired difference from none (t, BCa, percentile) | P(condition > none) [95% CI] |",
        "|---|---|---|---:|---:|---:|---:|",
        *rows,
        "",
        f"Primary comparison: {r.primary.comparison}. Verdict: **{r.primary.verdict}** ({result}).",
        EXPLORATORY_NOTE,
    ]
    return _section(r, result, md, figures)


def _mean_or_na(value: float | None, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


@render.register
def _(r: Claim1, ctx: Context) -> Section:
    rows = [
        f"| {x.learner} | {fmt(x.competitive)} | {fmt(x.cooperative)} | {intervals_text(x.difference)} | "
        f"{fmt(x.p)} | {' / '.join(_mean_or_na(v, '.2f') for v in x.after_clear)} | "
        f"{' / '.join(_mean_or_na(v, '.1f') for v in x.return_after_clear)} |"
        for x in r.rows
    ]
    figures = _curves_figures(ctx, "claim1.png", r.panels, "One treasure: competitive vs cooperative")
    result = f"difference {t_text(r.difference)} return units" if r.difference else NO_PRIMARY
    g = r.game
    md = [
        f"Setting: {plural(g.agents, 'agent')}, {plural(g.chests, 'chest')}, {plural(g.traps, 'trap')} on generated "
        f"{sides(g.sizes)} maps; {describe(r.evidence)}.",
        "",
        *_images(figures),
        "| learner | competitive | cooperative | cooperative - competitive (t, BCa, percentile) | "
        "P(cooperative > competitive) | after the chest is taken: episodes with an agent still playing, "
        "comp / coop | its return after it, comp / coop |",
        "|---|---:|---:|---:|---:|---:|---:|",
        *rows,
        "",
        "Does the announcement have any decision value here? Once the only chest is taken nothing is left to "
        f"find: every further move costs {joined(tuple(-v for v in g.step_reward), 'g')} wherever the agent goes, "
        f"and the episode ends only at the horizon or in a trap ({joined(g.trap_reward, 'g')}). Knowing that the "
        "chest is gone therefore cannot raise the team's return; it could only change where the remaining agent "
        "wanders. The last two columns measure how often that situation arises in the final "
        f"{r.final_tail:.0%} of evaluations and what it costs in each mode. By the game's rules, claim 1 holds by "
        "construction on one-chest maps, whatever the learner.",
        "",
        f"Primary comparison: {r.primary.comparison}. Rule: SUPPORTED if the interval lies below +{r.margin:g}, "
        f"NOT SUPPORTED if it lies above, INCONCLUSIVE otherwise. Verdict: **{r.primary.verdict}** ({result}).",
        EXPLORATORY_NOTE,
    ]
    return _section(r, result, md, figures)


@render.register
def _(r: Claim2, ctx: Context) -> Section:
    modes = ("competitive", "cooperative", "deliberative")
    rows = [
        f"| {x.learner} | {x.m} | "
        + " | ".join(fmt(x.levels[t]) for t in modes)
        + f" | {intervals_text(x.gaps[0])} | {intervals_text(x.gaps[1])} |"
        for x in r.rows
    ]
    finals = [f"| {x.learner} | {x.m} | " + " | ".join(fmt(x.finals[t]) for t in modes) + " |" for x in r.rows]
    trend_rows = []
    for trend in r.trends:
        last = list(trend.slopes)[-1]
        trend_rows += [  # the verdict on the learner's last slope row
            f"| {trend.learner} | {name} | {fmt(boot)} | {fmt(t)} |" + (f" {trend.verdict} |" if name == last else " |")
            for name, (boot, t) in trend.slopes.items()
        ]
        trend_rows += [
            f"| {trend.learner} | P({a} > {b}) at m = {trend.largest} | {fmt(p)} | | exploratory |"
            for a, b, p in trend.improvements
        ]
    figures = []
    if r.trends:
        figures.append(
            errorbar_figure(
                ctx.out / "claim2.png",
                [(f"{t.learner}: {SCORE_LABEL}", t.levels) for t in r.trends],
                "team size m (agents = chests = traps; the map grows with m)",
                "Score by team size and mode (mean, 95% bootstrap CI)",
                color_of=COLORS.get,
                watermark=ctx.watermark,
            ).name
        )
        gaps = {name: {t.learner: t.gaps[name] for t in r.trends} for name in r.trends[0].gaps}
        figures.append(
            errorbar_figure(
                ctx.out / "claim2_trend.png",
                [(f"{name} (score)", series) for name, series in gaps.items()],
                "team size m",
                "Gaps between modes by team size (paired by map and seed)",
                color_of=COLORS.get,
                watermark=ctx.watermark,
                zero_line=True,
            ).name
        )
    result = "; ".join(f"{name} slope {fmt(s)}" for name, s in r.slopes.items()) if r.slopes else NO_PRIMARY
    chests = "as many chests and traps" if r.as_many else "their maps' chests and traps"
    md = [
        f"Setting: teams of m = {', '.join(map(str, r.sizes))} agents with {chests} on generated maps "
        f"that grow with the team ({', '.join(sides(r.map_sides[m]) for m in r.sizes)}); {describe(r.evidence)}. "
        f"Score = {SCORE_LABEL}, averaged over training.",
        "",
        *_images(figures),
        "| learner | m | competitive | cooperative | deliberative | coop - comp | delib - coop |",
        "|---|---:|---:|---:|---:|---:|---:|",
        *rows,
        "",
        "| learner | difference | slope per extra agent, bootstrap [95% CI] | t [95% CI] | verdict |",
        "|---|---|---:|---:|---|",
        *trend_rows,
        "",
        "Every run has the same env-step budget, so larger teams on larger maps end further from convergence "
        "(final scores below): a gap's trend over m mixes the modes' effect with how far learning got.",
        "",
        f"| learner | m | final score (last {r.final_tail:.0%} of evaluations), IQM [95% CI]: competitive | "
        "cooperative | deliberative |",
        "|---|---:|---:|---:|---:|",
        *finals,
        "",
        f"Primary comparison: {r.primary.comparison}. Rule: SUPPORTED if both slopes' intervals lie above 0, "
        f"CONTRADICTED if either lies below 0, NOT SUPPORTED otherwise. Verdict: **{r.primary.verdict}** "
        f"({result}). The same rule applied to Double DQN is exploratory.",
    ]
    return _section(r, result, md, figures)


def _transfer_row(x: TransferRow, baseline: str) -> str:
    reached = f"{x.reached}/{x.runs}"
    if x.jump is None or x.difference is None or x.p is None or x.sooner is None or x.saved is None:
        return (
            f"| {x.learner} | {baseline} (the baseline) | {x.cost:,} | {fmt(x.score)} | — | — | — | {reached} | — | — |"
        )
    reuses = "—" if x.cost == 0 else (f"{x.cost / x.saved:.1f}" if x.saved > 0 else "never")
    return (
        f"| {x.learner} | {x.condition} | {x.cost:,} | {fmt(x.score)} | {fmt(x.jump)} | {intervals_text(x.difference)} "
        f"| {fmt(x.p)} | {reached} | {fmt(x.sooner)} | {reuses} |"
    )


@render.register
def _(r: Transfer, ctx: Context) -> Section:
    figures = _curves_figures(ctx, "transfer.png", r.panels, "Transfer: target-task steps") + _curves_figures(
        ctx,
        "transfer_total_steps.png",
        r.total_panels,
        "Transfer: total steps (each run starts after its source's pretraining)",
        xlabel="environment steps, the source's pretraining included",
        marks=[(c, "sources pretrained") for c in r.source_costs],
    )
    result = poi_result(r.p, r.difference)
    md = [
        f"Setting: teams of {joined(r.game.agents)} on {maps_text(r.game)}; {describe(r.evidence)}. The baseline is "
        f"`{r.baseline}`: random start with the transferred agents' exploration (epsilon from "
        f"{joined(r.matched_epsilon)}), so exploration alone cannot pass for transfer; `scratch` (epsilon from "
        f"{joined(r.scratch_epsilon)}) is shown against it too. Jumpstart and score differences are paired by map "
        f"and seed. Time to threshold: steps until the score first reaches {r.threshold:.0%} of the optimal "
        "return; P(sooner) counts a run that never gets there as slower than every run that does. Break-even "
        "reuses: the source's cost divided by the mean steps to threshold it saves a target run (a run that never "
        "gets there counted at its budget): how many runs must start from one source before it has paid for itself.",
        "",
        *_images(figures),
        "| learner | condition | source cost (steps) | score | jumpstart (first evaluation) | "
        f"score difference (t, BCa, percentile) | P(condition > baseline) | reached {r.threshold:.0%} | P(sooner) | "
        "break-even reuses |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        *(_transfer_row(x, r.baseline) for x in r.rows),
        "",
        f"Primary comparison: {r.primary.comparison}. Rule: SUPPORTED if the interval lies above 0.5, CONTRADICTED "
        f"if below, NOT SUPPORTED otherwise. Verdict: **{r.primary.verdict}** ({result}). Everything else is "
        "exploratory.",
    ]
    return _section(r, result, md, figures)


def _agents_word(agents: tuple[int, ...]) -> str:
    return "/".join(COUNT_WORDS.get(a, str(a)) for a in agents) + f" agent{'' if agents == (1,) else 's'}"


@render.register
def _(r: Curriculum, ctx: Context) -> Section:
    rows = [
        f"| {x.learner} | {x.start:,} | {fmt(x.jump)} | "
        f"{intervals_text(x.difference) if x.difference else 'no shared steps (unequal budgets)'} | "
        f"{' / '.join(fmt(f) for f in x.finals)} | {fmt(x.p)} |"
        for x in r.rows
    ]
    figures = _curves_figures(
        ctx,
        "curriculum.png",
        r.panels,
        "Curriculum vs scratch at equal total steps",
        xlabel="environment steps, the room stage's included",
        marks=[(c, "room stage ends") for c in r.stage_ends],
    )
    result = "; ".join(f"{x.learner}: P = {fmt(x.p)}" for x in r.rows) or "no runs"
    g, room = r.game, r.room
    team = "both agents" if g.agents == (2,) else f"all {joined(g.agents)} agents"
    md = [
        f"Setting: {article(sides(g.sizes))} {sides(g.sizes)} map with {plural(g.chests, 'chest')}, "
        f"{plural(g.traps, 'trap')} and "
        f"{plural(g.agents, 'agent')}; the curriculum first trains {_agents_word(room.agents)} on the "
        f"{sides(room.sizes)} room it contains (at {', '.join(map(str, r.room_offset))}), then {team} start from it; "
        f"{describe(r.evidence)} (the curriculum's own steps exclude the room's). Both conditions spend the same "
        "total env steps.",
        "",
        *_images(figures),
        "| learner | steps before (room) | score at the curriculum's start: curriculum - scratch | score over the "
        "shared steps: curriculum - scratch (t, BCa, percentile) | final score (equal budget): curriculum / "
        "scratch | P(curriculum > scratch), final |",
        "|---|---:|---:|---:|---:|---:|",
        *rows,
        "",
        "This comparison was added after the main rules and is exploratory: no verdict.",
    ]
    return _section(r, result, md, figures)


def _section(r: Result, result: str, md: list[str], figures: list[str]) -> Section:
    return Section(r.primary.question, r.primary.comparison, result, r.primary.verdict, "\n".join(md), figures)
