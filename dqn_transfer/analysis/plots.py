"""Learning-curve figures of run directories, and the other figures of the analyses (matplotlib, written to
files): estimates against an integer, performance profiles, and dose-response panels (a search's trials).

A group of runs (one condition, several seeds) is drawn as its mean curve over seeds with a 95%
percentile-bootstrap band (:func:`dqn_transfer.analysis.stats.curve_band`) and each run as a thin
line; a group of one run is one line. Axes say in words what they measure (:data:`METRIC_LABELS`).
:func:`group_runs` finds the groups of a set of runs by what differs between their configs, ignoring
the seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no display needed, no global backend set on import

from dqn_transfer.analysis.runs import learning_curve, load_config, steps_before
from dqn_transfer.analysis.stats import Estimate, curve_band, performance_profile
from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.storage.run_dir import flatten

# Keys that differ between runs of one condition without making it another condition.
IGNORED_KEYS = (
    "seed",
    "progress",
    "resume",
    "device",
    "checkpoint_every",
    "eval_pictures",
    "objective",
    "logger",
    "transfer.cache_dir",
    "replicas.workers",
)
# Keys that name a condition, preferred as labels over what they imply (agent=sarsa implies agent.lr).
PRIMARY_KEYS = ("agent.algorithm", "env.mode", "transfer.enabled", "env.num_agents", "env.layout_file", "env.layout")
LINESTYLES = ("-", "--", ":", "-.")  # besides colours: identical curves stay visible
ColorOf = Callable[[str], "str | None"]


# ------------------------------------------------------------------------------------ groups


def _short(key: str, value: Any) -> str:
    if key.endswith("layout_file") and isinstance(value, str):
        value = Path(value).name
    if key == "transfer.enabled":
        return "transfer=" + ("on" if value else "off")
    return f"{key.split('.')[-1] if key.startswith(('env.', 'agent.')) else key}={value}"


def group_runs(run_dirs: Sequence[Path]) -> dict[str, list[Path]]:
    """Runs grouped by the config keys that differ between them (the seed excluded), labelled by them.

    Runs without a readable config get a group (and a line) each.
    """
    configs = [load_config(d) for d in run_dirs]
    if any(c is None for c in configs):
        return {Path(d).name if Path(d).name not in ("", ".") else str(d): [Path(d)] for d in run_dirs}
    flats = [flatten(c) for c in configs]  # type: ignore[arg-type]
    keys = sorted({k for f in flats for k in f})
    varying = [k for k in keys if k not in IGNORED_KEYS and len({repr(f.get(k)) for f in flats}) > 1]
    # Keep only keys that split the runs further: agent=sarsa also changes agent.lr, which says nothing new.
    varying.sort(key=lambda k: (k not in PRIMARY_KEYS, PRIMARY_KEYS.index(k) if k in PRIMARY_KEYS else 0, k))
    chosen: list[str] = []
    for key in varying:
        before = len({tuple(repr(f.get(c)) for c in chosen) for f in flats})
        if len({tuple(repr(f.get(c)) for c in chosen + [key]) for f in flats}) > before:
            chosen.append(key)
    groups: dict[str, list[Path]] = {}
    for run, flat in zip(run_dirs, flats):
        label = ", ".join(_short(k, flat.get(k)) for k in chosen) or "all runs"
        groups.setdefault(label, []).append(Path(run))
    return dict(sorted(groups.items()))  # sorted labels: transfer=off beside transfer=on


# ------------------------------------------------------------------------------------ figures


# What a metrics.jsonl key measures, for axis labels a reader understands without the code.
METRIC_LABELS = {
    "team_return": "greedy evaluation team return",
    "score": "team return / the map's optimal return (greedy evaluation)",
    "success_rate": "fraction of the map's chests collected (greedy evaluation)",
    "trap_rate": "fraction of agents that end in a trap (greedy evaluation)",
    "episode_length": "greedy evaluation episode length (joint steps)",
}


def metric_label(metric: str) -> str:
    return METRIC_LABELS.get(metric, f"eval {metric}")


def plot_band(
    ax, curves: Sequence[Curve], label: str, rng: np.random.Generator, color=None, linestyle: str = "-"
) -> None:
    """Mean curve with its 95% CI band, and each run as a thin line (so bimodal outcomes show, which a
    mean hides); the legend says how many runs it rests on."""
    steps, mean, low, high = curve_band(curves, rng)
    n = len(curves)
    (line,) = ax.plot(steps, mean, label=f"{label} (n={n})", color=color, lw=1.8, ls=linestyle)
    if n > 1:
        ax.fill_between(steps, low, high, color=line.get_color(), alpha=0.2, lw=0)
        for run_steps, run_values in curves:
            ax.plot(run_steps, run_values, color=line.get_color(), lw=0.6, alpha=0.35, zorder=line.get_zorder() - 1)


def _band_panel(
    ax,
    metric: str,
    groups: dict[str, list[Curve]],
    rng: np.random.Generator,
    color_of: ColorOf | None,
    xlabel: str,
    legend_loc: str,
) -> None:
    """One axes: every group's mean curve and band, in the groups' order (so the rng draws are too)."""
    for index, (label, curves) in enumerate(groups.items()):
        plot_band(
            ax,
            curves,
            label,
            rng,
            color=color_of(label) if color_of else None,
            linestyle=LINESTYLES[index % len(LINESTYLES)],
        )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(metric_label(metric), fontsize="small")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc=legend_loc)


def _save(fig, path: Path, title: str | None, watermark: str | None = None, dpi: int = 110) -> Path:
    """Write the figure under its ``title`` (None: its axes carry their own); a ``watermark`` (e.g. a smoke
    run's "not evidence") is printed across it."""
    if title is not None:
        fig.suptitle(title)
    if watermark:
        fig.text(
            0.5,
            0.5,
            watermark,
            fontsize=28,
            color="red",
            alpha=0.25,
            ha="center",
            va="center",
            rotation=20,
            transform=fig.transFigure,
            zorder=10,
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, metadata={"Software": None})  # no version stamp: regenerated files stay identical
    return path


def plot_groups(
    groups: dict[str, list[Path]],
    metric: str,
    out: Path,
    title: str | None = None,
    seed: int = 0,
    total_steps: bool = False,
) -> Path:
    """One figure: every group's mean curve and band for ``metric``. With ``total_steps``, each run's
    curve starts at the steps spent before it (:func:`~dqn_transfer.analysis.runs.steps_before`: its
    source's pretraining, a curriculum's stages), marked by a dotted line, so conditions compare at
    equal total budgets."""
    rng = np.random.default_rng(seed)
    fig = Figure(figsize=(7.5, 4.5), constrained_layout=True)
    ax = fig.subplots()
    offsets = {d: steps_before(d) if total_steps else 0 for dirs in groups.values() for d in dirs}
    curves = {label: [_shifted(learning_curve(d, metric), offsets[d]) for d in dirs] for label, dirs in groups.items()}
    xlabel = "environment steps, counting those spent before each run" if total_steps else "environment steps"
    _band_panel(ax, metric, curves, rng, None, xlabel, "best")
    for offset in sorted(set(offsets.values()) - {0}):
        _mark(ax, offset, f"{offset:,} steps before")
    ax.set_title(title or f"{metric_label(metric)}: mean, 95% bootstrap CI and each run")
    return _save(fig, out, None, dpi=120)


def _mark(ax, x: float, text: str) -> None:
    """A dotted vertical line at ``x`` with its label along it."""
    ax.axvline(x, color="grey", ls=":", lw=1)
    ax.annotate(
        text,
        (x, 1),
        xycoords=("data", "axes fraction"),
        fontsize="x-small",
        rotation=90,
        va="top",
        ha="right",
        color="grey",
    )


def _shifted(curve: Curve, offset: int) -> Curve:
    steps, values = curve
    return steps + offset, values


def _grid(panels: int, width: float, height: float):
    """Figure and axes for ``panels`` panels, at most 3 a row (4 as 2 x 2)."""
    cols = 2 if panels == 4 else min(panels, 3)
    rows = -(-panels // cols)
    fig = Figure(figsize=(width * cols, height * rows), constrained_layout=True)
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.flat[panels:]:
        ax.set_visible(False)
    return fig, axes.flat


def curves_figure(
    path: Path,
    panels: list[tuple[str, dict[str, list[Curve]]]],
    title: str,
    rng: np.random.Generator,
    color_of: ColorOf | None = None,
    note: str | None = None,
    xlabel: str = "environment steps",
    watermark: str | None = None,
    marks: Sequence[tuple[float, str]] = (),
) -> Path:
    """Panels of learning curves (mean and 95% band per group, each run thin), one per ``(metric, groups)``;
    ``marks``: ``(x, label)`` dotted vertical lines on every panel."""
    fig, axes = _grid(len(panels), 6.2, 4.3)
    for ax, (metric, groups) in zip(axes, panels):
        _band_panel(ax, metric, groups, rng, color_of, xlabel + (f"\n{note}" if note else ""), "lower right")
        for x, text in marks:
            _mark(ax, x, text)
    return _save(fig, path, title + "\nmean, 95% bootstrap CI over runs, and each run (thin)", watermark)


def _whiskers(estimates: Sequence[Estimate]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(means, lows, highs)`` of estimates; an estimate without an interval is a bare point."""
    means = np.array([e.mean for e in estimates])
    lows = np.array([e.low if e.has_ci else e.mean for e in estimates])
    highs = np.array([e.high if e.has_ci else e.mean for e in estimates])
    return means, lows, highs


def errorbar_figure(
    path: Path,
    panels: list[tuple[str, dict[str, dict[int, Estimate]]]],
    xlabel: str,
    title: str,
    color_of: ColorOf | None = None,
    watermark: str | None = None,
    zero_line: bool = False,
) -> Path:
    """Panels side by side of estimates against an integer x, one per ``(ylabel, {series: {x: estimate}})``.

    Each series is a line with its 95% CIs as error bars, shifted sideways by its position so the
    bars of equal x stay apart; an empty series keeps its position (and line style) but is not drawn.
    """
    fig, axes = _grid(len(panels), 17 / 3, 4.5)
    for ax, (ylabel, series) in zip(axes, panels):
        if zero_line:
            ax.axhline(0.0, color="grey", lw=1)
        for index, (label, points) in enumerate(series.items()):
            if not points:
                continue
            xs, est = list(points), list(points.values())
            means, lows, highs = _whiskers(est)
            n = "/".join(sorted({str(e.n) for e in est}))
            offset = 0.08 * (index - (len(series) - 1) / 2)
            ax.errorbar(
                np.array(xs) + offset,
                means,
                yerr=[means - lows, highs - means],
                marker="o",
                capsize=4,
                ls=LINESTYLES[index % len(LINESTYLES)],
                label=f"{label} (n={n})",
                color=color_of(label) if color_of else None,
            )
        ax.set_xticks(sorted({x for points in series.values() for x in points}))
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel, fontsize="small")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    return _save(fig, path, title, watermark)


def dot_whisker_figure(
    path: Path,
    panels: list[tuple[str, dict[str, dict[str, Estimate]]]],
    xlabel: str,
    title: str,
    color_of: ColorOf | None = None,
    watermark: str | None = None,
    reference: float | None = None,
    shaded: tuple[float, float] | None = None,
) -> Path:
    """Panels side by side of estimates of named categories (one row each, e.g. methods), one per
    ``(panel title, {series: {category: estimate}})``: each series a dot with its 95% CI as a whisker, shifted
    up or down by its position so the rows' series stay apart; a vertical ``reference`` line (e.g. the
    optimum) where given, and a ``shaded`` band (e.g. the equivalence margins).
    """
    fig, axes = _grid(len(panels), 17 / 3, 4.5)
    for ax, (panel_title, series) in zip(axes, panels):
        categories = list(dict.fromkeys(c for points in series.values() for c in points))
        if reference is not None:
            ax.axvline(reference, color="grey", lw=1)
        if shaded is not None:
            ax.axvspan(*shaded, color="grey", alpha=0.15, lw=0)
        for index, (label, points) in enumerate(series.items()):
            offset = 0.15 * (index - (len(series) - 1) / 2)
            rows = [categories.index(c) + offset for c in points]
            means, lows, highs = _whiskers(list(points.values()))
            ax.errorbar(
                means,
                rows,
                xerr=[means - lows, highs - means],
                fmt="o",
                capsize=3,
                label=label,
                color=color_of(label) if color_of else None,
            )
        ax.set_yticks(range(len(categories)), categories)
        ax.invert_yaxis()
        ax.set_xlabel(xlabel)
        ax.set_title(panel_title, fontsize="medium")
        ax.grid(alpha=0.3, axis="x")
        ax.legend(fontsize="small")
    return _save(fig, path, title, watermark)


def profile_figure(
    path: Path,
    panels: list[tuple[str, dict[str, np.ndarray]]],
    title: str,
    rng: np.random.Generator,
    color_of: ColorOf | None = None,
    watermark: str | None = None,
) -> Path:
    """Performance profiles (rliable's score distributions): per panel, for each condition (scores
    ``[runs, maps]``), the fraction of runs scoring above tau, for every tau, with a 95%
    stratified-bootstrap band (:func:`~dqn_transfer.analysis.stats.performance_profile`)."""
    fig, axes = _grid(len(panels), 5.5, 4.0)
    for ax, (label, scores) in zip(axes, panels):
        low = min(float(np.min(s)) for s in scores.values())
        high = max(float(np.max(s)) for s in scores.values())
        taus = np.linspace(low, high, 61)
        for index, (name, condition) in enumerate(scores.items()):
            profile, band_low, band_high = performance_profile(condition, taus, rng)
            (line,) = ax.plot(
                taus,
                profile,
                label=f"{name} (n={condition.size})",
                ls=LINESTYLES[index % len(LINESTYLES)],
                color=color_of(name) if color_of else None,
            )
            ax.fill_between(taus, band_low, band_high, color=line.get_color(), alpha=0.15, lw=0)
        ax.set_title(label, fontsize="medium")
        ax.set_xlabel("final score tau (team return / optimal return)")
        ax.set_ylabel("fraction of runs with score > tau")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    return _save(fig, path, title, watermark)


@dataclass(frozen=True)
class DosePanel:
    """A dose-response panel: each series' (value, objective) points, its chosen point marked."""

    title: str
    xlabel: str
    log: bool  # a log x axis
    xlim: tuple[float, float]  # the whole range searched
    series: dict[str, tuple[list[float], list[float]]]  # label -> (values, objectives)
    chosen: dict[str, tuple[float, float]]  # label -> its marked point


def dose_response_figure(
    path: Path, panels: Sequence[DosePanel], title: str, ylabel: str, color_of: ColorOf | None = None
) -> Path:
    """Panels of points (a search's trials: a searched value against the objective), one colour per series,
    each series' chosen point a large star."""
    fig, axes = _grid(len(panels), 4.6, 3.6)
    for ax, panel in zip(axes, panels):
        for label, (xs, ys) in panel.series.items():
            color = color_of(label) if color_of else None
            points = ax.scatter(xs, ys, s=18, alpha=0.7, label=label, color=color)
            if label in panel.chosen:
                x, y = panel.chosen[label]
                ax.scatter([x], [y], s=160, marker="*", color=points.get_facecolor()[0], edgecolor="black", zorder=3)
        if panel.log:
            ax.set_xscale("log")
        ax.set_xlim(*panel.xlim)
        ax.set_title(panel.title, fontsize="medium")
        ax.set_xlabel(panel.xlabel, fontsize="small")
        ax.set_ylabel(ylabel, fontsize="small")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="x-small")
    return _save(fig, path, title)
