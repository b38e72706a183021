"""One report section per claim of the study, each with a verdict by a rule fixed in advance.

1. one treasure: cooperation gives no advantage over competition (``fig1``);
2. complex map, growing team: deliberative > cooperative > competitive (``fig2``);
3. transfer from a trained agent speeds up learning (``transfer``).

A section reads the runs of its experiment (their configs tell the conditions apart), computes its
statistics with :mod:`dqn_transfer.analysis` (95% percentile bootstraps over seeds; differences
between conditions paired by seed), draws its figures into ``OUT`` and states its verdict by the
rule in ``RULES``, which the report prints beside it. The section functions share one random
generator, in a fixed order of calls, so the same runs always give the same digits.

Figure 2 compares team sizes on the same map (:mod:`dqn_transfer.experiments.team_maps`); a run's
team size is read from its map, not from ``env.num_agents``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dqn_transfer.analysis.compare import compare_runs, format_table
from dqn_transfer.analysis.plots import curves_figure, errorbar_figure
from dqn_transfer.analysis.runs import Run, group, per_seed
from dqn_transfer.analysis.stats import Estimate, curve_band, difference, estimate
from dqn_transfer.analysis.transfer_metrics import Curve, asymptotic_performance, mean_curve, mean_over_training
from dqn_transfer.enums import Algorithm, Mode
from dqn_transfer.enums import values as enum_values
from dqn_transfer.experiments.sweeps import ReproduceError

FINAL_TAIL = 0.2  # "final performance" = mean of the last 20% of a run's evaluations
THRESHOLD_FRACTION = 0.9  # time to threshold: reach 90% of the baseline's improvement
EQUIVALENCE_MARGIN = 0.05  # claim 1: a cooperative advantage below 5% of the learning range is negligible
MODES = enum_values(Mode)
COMPETITIVE, COOPERATIVE, DELIBERATIVE = MODES
# One colour per condition across figures; transfer curves are labelled "<learner> transfer=off|on".
COLORS = {COMPETITIVE: "tab:red", COOPERATIVE: "tab:blue", DELIBERATIVE: "tab:green",
          "off": "tab:gray", "on": "tab:purple"}

RULES = {
    "claim1": ("An equivalence (non-superiority) test on the paired (same-seed) difference D = cooperative - "
               "competitive in mean evaluation team return over training (area under the curve / steps), with "
               f"margin delta = {EQUIVALENCE_MARGIN:.0%} of the competitive mean curve's range (max - min: the "
               "improvement learning brings). SUPPORTED if the 95% bootstrap CI of D lies below +delta (any "
               "advantage of cooperation is negligible); NOT SUPPORTED if it lies above +delta; INCONCLUSIVE if it "
               "straddles +delta (more seeds needed). The bare test 'the CI contains 0' is reported beside it: "
               "with many seeds it flags differences too small to matter, with few it passes anything."),
    "claim2": ("At the largest team size: SUPPORTED if the 95% bootstrap CIs of the paired (same-seed) "
               "differences deliberative - cooperative and cooperative - competitive in mean evaluation team return "
               "over training (area under the curve / steps: how well the team does while it learns) both lie "
               "above 0; NOT SUPPORTED otherwise. Final performance is reported beside it."),
    "claim3": ("Per learner: SUPPORTED if the 95% bootstrap CIs of the jumpstart and of the paired "
               "total-reward difference (transfer - baseline, area under the team-return curve) both "
               "lie above 0; NOT SUPPORTED otherwise. The claim as a whole is SUPPORTED if it holds for "
               "every learner tested, PARTLY SUPPORTED if for some."),
}


def team_size(config: dict[str, Any], out: Path | None = None) -> int:
    """Number of agents of a run's map: the start digits of its layout, else ``env.num_agents``."""
    env = config.get("env", {})
    layout = env.get("layout")
    if layout is None and env.get("layout_file"):
        path = Path(env["layout_file"])
        candidates = [path] + ([out / "maps" / path.name] if out is not None else [])  # OUT moved since
        for candidate in candidates:
            if candidate.is_file():
                layout = candidate.read_text()
                break
        else:
            raise ReproduceError(f"layout file {path} of a run is missing: cannot tell the team size")
    if layout is not None:
        return sum(ch.isdigit() for ch in layout)
    return int(env.get("num_agents") or env.get("num_treasures") or 1)


def final_performance(curve: Curve) -> float:
    return asymptotic_performance(curve, FINAL_TAIL)


def describe_runs(runs: Sequence[Run]) -> str:
    """How much evidence: seeds per condition, steps per run, evaluations."""
    steps = sorted({int(r.config.get("total_steps", 0)) for r in runs})
    every = sorted({int(r.config.get("eval_every", 0)) for r in runs})
    episodes = sorted({int(r.config.get("eval_episodes", 0)) for r in runs})
    fmt = lambda xs: "/".join(f"{x:,}" for x in xs)  # noqa: E731
    return (f"{fmt(steps)} environment steps per run, a greedy evaluation of {fmt(episodes)} episodes "
            f"every {fmt(every)} steps")


def seeds_of(groups: dict[Any, list[Run]]) -> str:
    counts = sorted({len(v) for v in groups.values()})
    return "/".join(map(str, counts))


@dataclass
class Section:
    """One claim's part of the report: its summary row (verdict, headline, evidence) and its Markdown."""

    claim: str
    verdict: str
    headline: str
    evidence: str
    markdown: str
    figures: list[str] = field(default_factory=list)


def _verdict(text: str) -> str:
    return f"**{text}**"


def _fig_path(out: Path, name: str) -> Path:
    return out / f"{name}.png"


def _color(label: str) -> str | None:
    return COLORS.get(label.split(" ")[-1].replace("transfer=", ""))


def _curves_figure(out: Path, name: str, panels: list[tuple[str, dict[str, list[Run]]]], title: str,
                   rng: np.random.Generator, note: str | None = None) -> Path:
    """Learning curves of groups of runs, one panel per ``(metric, {label: runs})``."""
    curves = [(metric, {label: [r.curve(metric) for r in members] for label, members in groups.items()})
              for metric, groups in panels]
    return curves_figure(_fig_path(out, name), curves, title, rng, color_of=_color, note=note)


def section_fig1(out: Path, runs: list[Run], rng: np.random.Generator) -> Section:
    by_mode = group(runs, lambda r: r.config["env"]["mode"])
    missing = [m for m in (COMPETITIVE, COOPERATIVE) if m not in by_mode]
    claim = "1. One treasure: cooperation gives no advantage over competition"
    if missing:
        return Section(claim, _verdict("INCONCLUSIVE"), f"no {', '.join(missing)} runs", "", f"No {', '.join(missing)} runs in {out / 'fig1'}.")
    comp, coop = by_mode[COMPETITIVE], by_mode[COOPERATIVE]
    sample = comp[0].config["env"]
    setting = (f"{comp[0].config['agent']['algorithm']} on a {sample.get('size')}x{sample.get('size')} map with "
               f"{sample.get('num_treasures')} treasure, {sample.get('num_traps')} trap(s) and "
               f"{team_size(comp[0].config, out)} agents")
    modes = {COMPETITIVE: comp, COOPERATIVE: coop}
    fig = _curves_figure(out, "fig1", [("team_return", modes), ("success_rate", modes)],
                         "Figure 1: one treasure, competitive vs cooperative", rng)
    auc = {m: per_seed(g, mean_over_training) for m, g in modes.items()}
    fin = {m: per_seed(g, final_performance) for m, g in modes.items()}
    succ = {m: per_seed(g, final_performance, "success_rate") for m, g in modes.items()}
    d_auc = difference(auc[COOPERATIVE], auc[COMPETITIVE], rng)
    d_fin = difference(fin[COOPERATIVE], fin[COMPETITIVE], rng)
    d_succ = difference(succ[COOPERATIVE], succ[COMPETITIVE], rng)
    # Only the mean is used; the band's one resample still draws from rng, as the report always has,
    # so the same runs keep giving the same intervals below.
    _, comp_mean, _, _ = curve_band([r.curve() for r in comp], rng, n_resamples=1)
    delta = EQUIVALENCE_MARGIN * float(comp_mean.max() - comp_mean.min())
    bare = ("contains 0" if d_auc.contains_zero() else "excludes 0") if d_auc.has_ci else "is undefined"
    if not d_auc.has_ci:
        verdict, why = "INCONCLUSIVE", "fewer than 2 seeds: no confidence interval"
    elif d_auc.high < delta:
        verdict = "SUPPORTED"
        why = (f"the 95% CI of cooperative - competitive, {d_auc}, lies below the margin +{delta:.3g} "
               f"(the CI {bare}): any advantage of cooperation is at most {max(d_auc.high, 0):.3g} return units")
    elif d_auc.low > delta:
        verdict = "NOT SUPPORTED"
        why = f"the 95% CI of cooperative - competitive, {d_auc}, lies above the margin +{delta:.3g}: cooperation helps"
    else:
        verdict = "INCONCLUSIVE"
        why = (f"the 95% CI of cooperative - competitive, {d_auc}, straddles the margin +{delta:.3g} (the CI {bare}): "
               "run more seeds")
    table = ["| metric (per run) | competitive | cooperative | cooperative - competitive (paired) |",
             "|---|---:|---:|---:|"]
    for label, values, diff in (("mean eval team return over training (AUC / steps)", auc, d_auc),
                                (f"final team return (last {FINAL_TAIL:.0%} of evals)", fin, d_fin),
                                (f"final success rate (last {FINAL_TAIL:.0%} of evals)", succ, d_succ)):
        table.append(f"| {label} | {estimate(list(values[COMPETITIVE].values()), rng)} | "
                     f"{estimate(list(values[COOPERATIVE].values()), rng)} | {diff} |")
    evidence = f"{seeds_of(by_mode)} seeds per mode; {describe_runs(runs)}"
    md = "\n".join([
        f"Setting: {setting}. Evidence: {evidence}.", "",
        f"![Figure 1]({fig.name})", "",
        "Means with 95% percentile-bootstrap CIs over seeds:", "", *table, "",
        f"Rule: {RULES['claim1']}", "",
        f"Verdict: {_verdict(verdict)} — {why}.",
    ])
    return Section(claim, _verdict(verdict), f"coop - comp mean return {d_auc} (margin +{delta:.3g})", evidence, md,
                   [fig.name])


def _mode_differences(values: dict[tuple[str, int], dict[int, float]], m: int, rng: np.random.Generator):
    """(coop - comp, delib - coop) at team size m, paired by seed; None where a mode is missing."""
    def diff(a: str, b: str) -> Estimate | None:
        return difference(values[(a, m)], values[(b, m)], rng) if (a, m) in values and (b, m) in values else None
    return diff(COOPERATIVE, COMPETITIVE), diff(DELIBERATIVE, COOPERATIVE)


def _mode_table(values: dict[tuple[str, int], dict[int, float]], sizes: list[int], rng: np.random.Generator,
                with_differences: bool = True) -> tuple[list[str], dict[int, tuple]]:
    """Markdown rows: per team size, each mode's mean [CI] and the two paired differences."""
    head = "| team size | competitive | cooperative | deliberative |"
    rows = [head + (" coop - comp | delib - coop |" if with_differences else ""),
            "|---:|---:|---:|---:|" + ("---:|---:|" if with_differences else "")]
    diffs = {}
    for m in sizes:
        cells = " | ".join(str(estimate(list(values[(mode, m)].values()), rng)) if (mode, m) in values else "—"
                           for mode in MODES)
        diffs[m] = _mode_differences(values, m, rng)
        extra = f" {diffs[m][0] or '—'} | {diffs[m][1] or '—'} |" if with_differences else ""
        rows.append(f"| {m} | {cells} |{extra}")
    return rows, diffs


def section_fig2(out: Path, runs: list[Run], rng: np.random.Generator) -> Section:
    claim = "2. Complex map, growing team: deliberative > cooperative > competitive"
    cells = group(runs, lambda r: (r.config["env"]["mode"], team_size(r.config, out)))
    sizes = sorted({m for _, m in cells})
    if not sizes:
        return Section(claim, _verdict("INCONCLUSIVE"), "no runs", "", "No runs.")
    metrics = {  # per (mode, team size): {seed: value}
        "mean_return": {k: per_seed(g, mean_over_training) for k, g in cells.items()},
        "final_return": {k: per_seed(g, final_performance) for k, g in cells.items()},
        "final_success": {k: per_seed(g, final_performance, "success_rate") for k, g in cells.items()},
    }
    labels = {"mean_return": "mean eval team return over training (AUC / steps)",
              "final_return": f"final eval team return (last {FINAL_TAIL:.0%} of evals)",
              "final_success": f"final eval success rate (last {FINAL_TAIL:.0%})"}

    # Figure 2: each metric against team size, one line per mode.
    points = [(labels[name], {mode: {m: estimate(list(values[(mode, m)].values()), rng) for m in sizes
                                     if (mode, m) in values} for mode in MODES})
              for name, values in metrics.items()]
    fig2 = errorbar_figure(_fig_path(out, "fig2"), points, "team size (agents, same map)",
                           "Figure 2: complex map — performance vs team size (mean, 95% bootstrap CI over seeds)",
                           color_of=_color)
    largest = sizes[-1]
    curves = _curves_figure(out, "fig2_curves", [(metric, {mode: cells[(mode, largest)] for mode in MODES
                                                           if (mode, largest) in cells})
                                                 for metric in ("team_return", "success_rate")],
                            f"Complex map, team of {largest}", rng)

    rows_primary, diffs = _mode_table(metrics["mean_return"], sizes, rng)
    rows_final, diffs_final = _mode_table(metrics["final_return"], sizes, rng)
    rows_success, _ = _mode_table(metrics["final_success"], sizes, rng, with_differences=False)
    d_cc, d_dc = diffs[largest]
    if d_cc is None or d_dc is None:
        verdict, why = "INCONCLUSIVE", f"a mode is missing at team size {largest}"
    elif not (d_cc.has_ci and d_dc.has_ci):
        verdict, why = "INCONCLUSIVE", "fewer than 2 seeds: no confidence interval"
    elif largest < 2:
        verdict, why = "INCONCLUSIVE", "only single-agent teams were run"
    elif d_cc.excludes_zero_above() and d_dc.excludes_zero_above():
        verdict = "SUPPORTED"
        why = f"at team size {largest}, deliberative - cooperative = {d_dc} and cooperative - competitive = {d_cc}, both CIs above 0"
    else:
        verdict = "NOT SUPPORTED"
        failed = [name for name, d in (("deliberative > cooperative", d_dc), ("cooperative > competitive", d_cc))
                  if not d.excludes_zero_above()]
        why = (f"at team size {largest}, deliberative - cooperative = {d_dc} and cooperative - competitive = "
               f"{d_cc}; not established: {' and '.join(failed)}")
    f_cc, f_dc = diffs_final[largest]
    secondary = (f"On final team return instead (secondary, not the rule): deliberative - cooperative = {f_dc}, "
                 f"cooperative - competitive = {f_cc} at team size {largest}." if f_cc and f_dc else "")
    trend = ", ".join(f"m={m}: {diffs[m][1].mean:+.3g} / {diffs[m][0].mean:+.3g}" for m in sizes
                      if diffs[m][0] is not None and diffs[m][1] is not None)
    sample = runs[0].config
    evidence = f"{seeds_of(cells)} seeds per (mode, team size); {describe_runs(runs)}"
    notes = []
    if 1 in sizes and diffs[1][0] is not None and diffs[1][0].has_ci and diffs[1][0].low == diffs[1][0].high == 0:
        notes.append("Sanity check passed: with one agent, competitive and cooperative runs of the same seed are "
                     "identical (there is nobody to announce anything), so their difference is exactly 0.")
    maps = sorted({Path(r.config["env"]["layout_file"]).name if r.config["env"].get("layout_file") else "generated"
                   for r in runs})
    md = "\n".join([
        f"Setting: {sample['agent']['algorithm']} on the complex map ({', '.join(f'`{m}`' for m in maps)}: the same "
        "map for every team size, start digits >= m removed; `maps/` beside this report). An agent is done after "
        "taking one treasure, so a team of m collects at most m of the map's chests. Evidence: " + evidence + ".", "",
        f"![Figure 2]({fig2.name})", "",
        f"![Learning curves at team size {largest}]({curves.name})", "",
        "Primary metric — mean evaluation team return over training (area under the curve / steps), "
        "mean [95% CI]; differences paired by seed:", "", *rows_primary, "",
        f"Final team return (mean of the last {FINAL_TAIL:.0%} of evaluations):", "", *rows_final, "",
        "Final success rate (fraction of the map's chests collected):", "", *rows_success, "",
        f"Differences delib - coop / coop - comp in the primary metric by team size (does the gap grow?): {trend}.",
        "", *(n + "\n" for n in notes),
        f"Rule: {RULES['claim2']}", "",
        f"Verdict: {_verdict(verdict)} — {why}. {secondary}",
    ])
    headline = f"m={largest}: delib - coop {d_dc}, coop - comp {d_cc}" if d_cc and d_dc else "—"
    return Section(claim, _verdict(verdict), headline, evidence, md, [fig2.name, curves.name])


def transfer_threshold(baseline: Sequence[Run]) -> float | None:
    """``THRESHOLD_FRACTION`` of the way from the mean baseline curve's lowest value to its final value."""
    steps, mean = mean_curve([r.curve() for r in baseline])
    final = asymptotic_performance((steps, mean), 0.1)
    low = float(mean.min())
    if final <= low:
        return None
    return low + THRESHOLD_FRACTION * (final - low)


def section_transfer(out: Path, runs: list[Run], rng: np.random.Generator) -> Section:
    claim = "3. Transfer from an already trained agent speeds up learning"
    cells = group(runs, lambda r: (r.config["agent"]["algorithm"], bool(r.config["transfer"]["enabled"])))
    algorithms = sorted({a for a, _ in cells}, key=lambda a: (a != Algorithm.double_dqn.value, a))
    parts, verdicts, headlines, figs = [], {}, [], []
    panels = []
    for algorithm in algorithms:
        on, off = cells.get((algorithm, True)), cells.get((algorithm, False))
        if not on or not off:
            verdicts[algorithm] = "INCONCLUSIVE"
            parts.append(f"### {algorithm}\n\nMissing the transfer={'on' if not on else 'off'} runs.")
            continue
        panels.append((algorithm, {f"{algorithm} transfer=off": off, f"{algorithm} transfer=on": on}))
        threshold = transfer_threshold(off)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            results = compare_runs([r.dir for r in on], [r.dir for r in off], threshold=threshold,
                                   seed=int(rng.integers(2**31)))
        js, tr = Estimate(**results["jumpstart"]), Estimate(**results["total_reward/difference"])
        if not (js.has_ci and tr.has_ci):
            verdict, why = "INCONCLUSIVE", "fewer than 2 seeds: no confidence interval"
        elif js.excludes_zero_above() and tr.excludes_zero_above():
            verdict, why = "SUPPORTED", f"jumpstart {js} and total-reward difference {tr} both have CIs above 0"
        else:
            verdict = "NOT SUPPORTED"
            failed = [n for n, e in (("jumpstart", js), ("total reward", tr)) if not e.excludes_zero_above()]
            why = f"jumpstart {js}, total-reward difference {tr}; CI not above 0 for: {', '.join(failed)}"
        verdicts[algorithm] = verdict
        headlines.append(f"{algorithm}: jumpstart {js}, ΔAUC {tr}")
        pre = sorted({int(r.config["transfer"].get("pretrain_steps", 0)) for r in on})
        source = on[0].config["transfer"].get("source")
        origin = (f"the source agent was pretrained on TreasureHunt-v0 (the single-agent MDP of the same map) for "
                  f"{'/'.join(f'{p:,}' for p in pre)} steps per seed; those steps are not on the curves"
                  if source is None else f"source: {source}")
        eps = sorted({on[0].config["transfer"].get("epsilon_start")})
        if threshold is not None:
            reached_on = results["time_to_threshold/transfer"]["n"]
            reached_off = results["time_to_threshold/baseline"]["n"]
            thr = (f"time to threshold: first evaluation reaching {threshold:.4g}, {THRESHOLD_FRACTION:.0%} of the way "
                   f"from the mean baseline curve's lowest to its final value; {reached_on} of {len(on)} transfer and "
                   f"{reached_off} of {len(off)} baseline runs reach it, the others are left out of its rows")
        else:
            thr = "time to threshold: not computed (the baseline curve never improves)"
        parts.append("\n".join([
            f"### {algorithm}", "",
            f"{len(on)} transfer / {len(off)} baseline seeds; {describe_runs(on + off)}; {origin}; transferred "
            f"agents start exploring at epsilon {eps[0]} (baseline: {off[0].config['agent'].get('eps_start')}).", "",
            "Taylor & Stone (2009) metrics on eval team return, mean [95% bootstrap CI] "
            "(jumpstart and `/difference` paired by seed; transfer ratio against the mean baseline curve; "
            f"{thr}):", "",
            format_table(results), "",
            f"Verdict for {algorithm}: {_verdict(verdict)} — {why}.",
        ]))
    if panels:
        fig = _curves_figure(out, "transfer", [("team_return", groups) for _, groups in panels],
                             "Transfer on vs off", rng, note="(source pretraining steps not shown)")
        figs.append(fig.name)
    values = list(verdicts.values())
    if not values or all(v == "INCONCLUSIVE" for v in values):
        overall = "INCONCLUSIVE"
    elif all(v == "SUPPORTED" for v in values):
        overall = "SUPPORTED"
    elif any(v == "SUPPORTED" for v in values):
        overall = "PARTLY SUPPORTED"
    else:
        overall = "NOT SUPPORTED"
    evidence = f"{seeds_of(cells)} seeds per (learner, transfer); {describe_runs(runs)}"
    md = "\n".join([
        *(f"![Transfer learning curves]({f})\n" for f in figs),
        "\n\n".join(parts), "",
        f"Rule: {RULES['claim3']}", "",
        f"Verdict: {_verdict(overall)} — " + "; ".join(f"{a}: {v.lower()}" for a, v in verdicts.items()) + ".",
    ])
    return Section(claim, _verdict(overall), "; ".join(headlines) or "—", evidence, md, figs)


SECTIONS = {"fig1": section_fig1, "fig2": section_fig2, "transfer": section_transfer}
