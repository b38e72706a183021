#!/usr/bin/env python
"""Reproduce the study's three claims: run the sweeps, then write ``OUT/REPORT.md`` and figures.

    python scripts/reproduce.py --profile quick --out /tmp/repro_quick   # smoke run: minutes, 2-3 seeds
    python scripts/reproduce.py --profile full --out results/            # the evidence: >= 10 seeds, ~30 min on 2 cores
    python scripts/reproduce.py --profile full --out results/ --launcher submitit_slurm \\
        --extra hydra.launcher.partition=PART --extra hydra.launcher.timeout_min=120
    python scripts/reproduce.py --out results/ --report-only             # re-analyse runs already there
    python scripts/reproduce.py --write-maps maps/                        # only the Figure 2 team maps

Each experiment is one Hydra multirun of ``train.py -m experiment=<name>`` (``conf/experiment/``)
into ``OUT/<name>/`` (a subprocess; ``--launcher joblib`` runs ``--n-jobs`` jobs at a time). The
``full`` profile uses the experiment files' own step counts; ``quick`` shrinks them and the seeds.
Then the run directories are read back (``.hydra/config.yaml`` + ``metrics.jsonl``, never live
objects) with :mod:`dqn_transfer.evaluation`, and the report says, for each claim, whether the data
support it, by a rule fixed in advance (see ``RULES``):

1. one treasure: cooperation gives no advantage over competition (``fig1``);
2. complex map, growing team: deliberative > cooperative > competitive (``fig2``);
3. transfer from a trained agent speeds up learning (``transfer``).

Figure 2 compares team sizes on the SAME map: the 4-agent map is generated once and its m-agent
versions drop the start digits >= m (``OUT/maps/fig2_m{m}.txt``); changing ``env.num_agents``
instead would generate a different map for every team size.

A sweep directory already complete for the same settings is reused (so a failed report or a second
``--only`` does not rerun it); one holding other or unfinished runs is an error, never overwritten.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import shlex
import subprocess
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

SCRIPTS = Path(__file__).resolve().parent
ROOT = SCRIPTS.parent
for _path in (ROOT, SCRIPTS):  # run as a file from anywhere, without installing the package
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

import plot as plotting  # noqa: E402  (scripts/plot.py)
from dqn_transfer.evaluation import (  # noqa: E402
    METRICS_FILE,
    EvaluationError,
    asymptotic_performance,
    bootstrap_ci,
    compare_runs,
    format_table,
    learning_curve,
    read_metrics,
    total_reward,
)

EXPERIMENTS = ("fig1", "fig2", "transfer")
TRAIN = ROOT / "train.py"
FINAL_TAIL = 0.2  # "final performance" = mean of the last 20% of a run's evaluations
THRESHOLD_FRACTION = 0.9  # time to threshold: reach 90% of the baseline's improvement
EQUIVALENCE_MARGIN = 0.05  # claim 1: a cooperative advantage below 5% of the learning range is negligible
MODES = ("competitive", "cooperative", "deliberative")
COLORS = {"competitive": "tab:red", "cooperative": "tab:blue", "deliberative": "tab:green",
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


class ReproduceError(Exception):
    """A failed sweep or unusable results; the message is for the user, ``main`` exits 1."""


# ================================================================================ profiles


@dataclass(frozen=True)
class Profile:
    """Seeds per experiment, and overrides of the experiment file's settings (none: the file's own)."""

    seeds: dict[str, int]
    overrides: dict[str, list[str]] = field(default_factory=dict)
    description: str = ""


PROFILES = {
    "quick": Profile(
        seeds={"fig1": 3, "fig2": 2, "transfer": 3},
        overrides={
            "fig1": ["total_steps=2000", "eval_every=100"],
            "fig2": ["total_steps=30000", "eval_every=2000", "eval_episodes=5"],
            "transfer": ["total_steps=2000", "eval_every=100", "transfer.pretrain_steps=2000",
                         "agent.learning_starts=200"],
        },
        description="SMOKE RUN: 2-3 seeds and a few thousand steps per run; it checks that the pipeline "
                    "works end to end and is NOT evidence for or against any claim."),
    "full": Profile(
        seeds={"fig1": 20, "fig2": 10, "transfer": 10},
        description="the evidence: >= 10 seeds per condition, step counts of conf/experiment/*.yaml."),
}


def _quote(value: str | Path) -> str:
    """A path as a Hydra override value (quoted: spaces, '=' and ',' are grammar)."""
    text = str(value)
    if "'" in text:
        raise ReproduceError(f"{text}: paths with a single quote cannot be passed to Hydra; choose another --out")
    return f"'{text}'"


def team_map_layouts(size: int, num_treasures: int, num_traps: int | None, num_agents: int,
                     complexity: float, map_seed: int) -> dict[int, str]:
    """The ``num_agents``-agent generated map and its m-agent versions (starts >= m made free)."""
    from dqn_transfer.envs import generate_layout, parse_layout

    full = generate_layout(size, num_treasures, num_traps, num_agents, complexity, seed=map_seed)
    layouts = {}
    for m in range(1, num_agents + 1):
        layout = "".join("." if ch.isdigit() and int(ch) >= m else ch for ch in full)
        parse_layout(layout)  # every map rule still holds: only starts became free cells
        layouts[m] = layout
    return layouts


def write_team_maps(directory: Path) -> list[Path]:
    """``fig2_m{1..K}.txt``: the complex map (conf/env/complex.yaml) for teams of 1..K agents."""
    env = yaml.safe_load((ROOT / "conf" / "env" / "complex.yaml").read_text())
    layouts = team_map_layouts(env["size"], env["num_treasures"], env.get("num_traps"),
                               env.get("num_agents") or env["num_treasures"], env.get("complexity", 0.0),
                               env.get("map_seed", 0))
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for m, layout in layouts.items():
        path = directory / f"fig2_m{m}.txt"
        path.write_text(layout + "\n")
        paths.append(path)
    return paths


def sweep_overrides(name: str, profile: str, out: Path) -> list[str]:
    """The command-line overrides of one experiment's multirun (they replace the file's sweep keys)."""
    prof = PROFILES[profile]
    seeds = [f"seed=range(0,{prof.seeds[name]})"]
    if name == "fig1":
        sweep = ["mode=competitive,cooperative"]
    elif name == "fig2":
        maps = write_team_maps(out / "maps")
        sweep = ["mode=" + ",".join(MODES), "env.num_agents=null",
                 "env.layout_file=" + ",".join(_quote(p) for p in maps)]
    elif name == "transfer":
        sweep = ["transfer=off,on", "agent=double_dqn,sarsa", f"transfer.cache_dir={_quote(out / 'pretrained')}"]
    else:
        raise ReproduceError(f"unknown experiment {name!r} (choose from {', '.join(EXPERIMENTS)})")
    return sweep + seeds + prof.overrides.get(name, [])


def count_jobs(name: str, overrides: Sequence[str]) -> int:
    """How many jobs the multirun launches: the experiment file's sweep with ``overrides`` applied."""
    from hydra import compose, initialize_config_dir
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from dqn_transfer.config import register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"experiment={name}"], return_hydra_config=True)
    params = {key: str(value) for key, value in (cfg.hydra.sweeper.params or {}).items()}
    parser = OverridesParser.create()
    for text, override in zip(overrides, parser.parse_overrides(list(overrides))):
        params[override.get_key_element()] = text.split("=", 1)[1]  # the command line replaces a file's key
    total = 1
    for override in parser.parse_overrides([f"{k}={v}" for k, v in params.items()]):
        if override.is_sweep_override():
            total *= len(list(override.sweep_string_iterator()))
    return total


# ================================================================================ running


def launcher_overrides(launcher: str, n_jobs: int) -> list[str]:
    if launcher == "basic":
        return []
    if launcher == "joblib":
        return ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={n_jobs}"]
    return [f"hydra/launcher={launcher}"]  # e.g. submitit_slurm / submitit_local, with --extra settings


def run_is_complete(run_dir: Path) -> bool:
    """The run evaluated at its last step (the trainer's final act before its last checkpoint)."""
    config = plotting.load_config(run_dir)
    if config is None or not (run_dir / METRICS_FILE).is_file():
        return False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            records = read_metrics(run_dir)
    except EvaluationError:
        return False
    return bool(records) and max(int(r.get("step", -1)) for r in records) >= int(config.get("total_steps", 0))


def job_dirs(sweep_dir: Path) -> list[Path]:
    """Hydra's numbered job directories of a multirun."""
    if not sweep_dir.is_dir():
        return []
    return sorted((p for p in sweep_dir.iterdir() if p.is_dir() and p.name.isdigit()), key=lambda p: int(p.name))


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").rstrip().splitlines()
    except OSError:
        return f"    ({path} is unreadable)"
    return "\n".join("    " + line for line in text[-lines:]) or "    (empty)"


def failure_message(name: str, sweep_dir: Path, log_path: Path, expected: int, returncode: int) -> str:
    """Which runs failed, with the tail of each one's log, or of the sweep log if no run explains it."""
    runs = job_dirs(sweep_dir)
    bad = [d for d in runs if not run_is_complete(d)]
    parts = [f"experiment {name} failed (exit code {returncode}): {len(runs) - len(bad)}/{expected} runs "
             f"complete in {sweep_dir}"]
    for run in bad[:5]:
        overrides = run / ".hydra" / "overrides.yaml"
        what = " ".join(yaml.safe_load(overrides.read_text()) or []) if overrides.exists() else "?"
        log = run / "train.log"
        parts.append(f"  run {run} ({what}) is incomplete; tail of {log}:\n{_tail(log)}")
    if len(bad) > 5:
        parts.append(f"  ... and {len(bad) - 5} more incomplete runs")
    if len(runs) < expected:
        parts.append(f"  {expected - len(runs)} jobs never started")
    parts.append(f"  tail of the sweep log {log_path}:\n{_tail(log_path, 25)}")
    return "\n".join(parts)


def run_experiment(name: str, profile: str, out: Path, launcher: str, n_jobs: int,
                   extra: Sequence[str] = (), poll_seconds: float = 2.0) -> float:
    """One Hydra multirun into ``OUT/<name>``; returns its wall time (0 when reused)."""
    sweep_dir = out / name
    overrides = sweep_overrides(name, profile, out)
    expected = count_jobs(name, overrides)
    stamp_path = sweep_dir / "reproduce.json"
    stamp = {"experiment": name, "profile": profile, "overrides": overrides, "jobs": expected}
    if sweep_dir.exists() and any(sweep_dir.iterdir()):
        previous = json.loads(stamp_path.read_text()) if stamp_path.exists() else None
        same = previous is not None and {k: previous.get(k) for k in stamp} == stamp
        if same and len(job_dirs(sweep_dir)) == expected and all(run_is_complete(d) for d in job_dirs(sweep_dir)):
            print(f"[{name}] reusing the {expected} complete runs in {sweep_dir}", flush=True)
            return 0.0
        what = "runs of other settings" if previous is not None and not same else "unfinished runs"
        raise ReproduceError(f"{sweep_dir} already holds {what}; delete it or choose another --out "
                             "(--report-only analyses what is there)")
    command = [sys.executable, str(TRAIN), "-m", f"experiment={name}", *overrides,
               f"hydra.sweep.dir={_quote(sweep_dir)}", "progress=false",
               *launcher_overrides(launcher, n_jobs), *extra]
    log_path = out / "logs" / f"{name}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env.setdefault(var, "1")  # parallel jobs of small MLPs: more torch threads only contend
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    how = f"{launcher}" + (f", {n_jobs} at a time" if launcher == "joblib" else "")
    print(f"[{name}] {expected} jobs ({how}) -> {sweep_dir}\n[{name}] log: {log_path}", flush=True)
    start = time.perf_counter()
    with log_path.open("w") as log:
        log.write("$ " + shlex.join(command) + "\n\n")
        log.flush()
        process = subprocess.Popen(command, cwd=out, stdout=log, stderr=subprocess.STDOUT, env=env)
        done, printed = -1, -math.inf
        while process.poll() is None:
            time.sleep(poll_seconds)
            now = sum(run_is_complete(d) for d in job_dirs(sweep_dir))
            elapsed = time.perf_counter() - start
            if now != done and (elapsed - printed >= 10 or now == expected):  # a line per change, at most every 10 s
                done, printed = now, elapsed
                print(f"[{name}] {done}/{expected} runs done ({elapsed:.0f} s)", flush=True)
    elapsed = time.perf_counter() - start
    runs = job_dirs(sweep_dir)
    if process.returncode != 0 or len(runs) != expected or not all(run_is_complete(d) for d in runs):
        raise ReproduceError(failure_message(name, sweep_dir, log_path, expected, process.returncode))
    stamp["wall_seconds"] = round(elapsed, 1)
    stamp_path.write_text(json.dumps(stamp, indent=2) + "\n")
    print(f"[{name}] {expected}/{expected} runs done in {elapsed:.0f} s", flush=True)
    return elapsed


# ================================================================================ reading runs


@dataclass
class Run:
    dir: Path
    config: dict[str, Any]

    @property
    def seed(self) -> int:
        return int(self.config.get("seed", 0))

    def curve(self, metric: str = "team_return"):
        return learning_curve(self.dir, metric)


def load_runs(sweep_dir: Path) -> list[Run]:
    """Every run below ``sweep_dir`` with a config and evaluations."""
    if not sweep_dir.is_dir():
        return []
    runs = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        for run_dir in plotting.find_run_dirs([sweep_dir]) if any(sweep_dir.rglob(METRICS_FILE)) else []:
            config = plotting.load_config(run_dir)
            if config is None:
                raise ReproduceError(f"{run_dir}: no readable .hydra/config.yaml; cannot tell its condition")
            runs.append(Run(Path(run_dir), config))
    return runs


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


def group(runs: Sequence[Run], key: Callable[[Run], Any]) -> dict[Any, list[Run]]:
    groups: dict[Any, list[Run]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    for members in groups.values():
        members.sort(key=lambda r: r.seed)
    return groups


# ================================================================================ statistics


@dataclass
class Estimate:
    mean: float
    low: float
    high: float
    n: int

    @property
    def has_ci(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)

    def excludes_zero_above(self) -> bool:
        return self.has_ci and self.low > 0

    def contains_zero(self) -> bool:
        return self.has_ci and self.low <= 0 <= self.high

    def __str__(self) -> str:
        if not math.isfinite(self.mean):
            return "n/a"
        ci = f"[{self.low:.4g}, {self.high:.4g}]" if self.has_ci else "[CI n/a]"
        return f"{self.mean:.4g} {ci}"


def estimate(values: Sequence[float], rng: np.random.Generator) -> Estimate:
    values = [v for v in values if math.isfinite(v)]
    if not values:
        return Estimate(math.nan, math.nan, math.nan, 0)
    return Estimate(*bootstrap_ci(values, rng), len(values))


def difference(a: dict[int, float], b: dict[int, float], rng: np.random.Generator,
               n_resamples: int = 10000) -> Estimate:
    """Mean of ``a - b`` with a 95% bootstrap CI: paired by seed when both have the same seeds
    (same map, same initial values and exploration noise cancel), else two independent samples."""
    if set(a) == set(b):
        return estimate([a[s] - b[s] for s in sorted(a)], rng)
    av, bv = np.array(list(a.values())), np.array(list(b.values()))
    mean = float(av.mean() - bv.mean())
    if av.size < 2 or bv.size < 2:
        return Estimate(mean, math.nan, math.nan, min(av.size, bv.size))
    diffs = (av[rng.integers(0, av.size, (n_resamples, av.size))].mean(1)
             - bv[rng.integers(0, bv.size, (n_resamples, bv.size))].mean(1))
    low, high = np.quantile(diffs, [0.025, 0.975])
    return Estimate(mean, float(low), float(high), min(av.size, bv.size))


def mean_return_over_training(curve) -> float:
    """Area under the curve divided by the steps it spans: the average evaluation return, in return units."""
    steps, values = curve
    span = float(steps[-1] - steps[0])
    return total_reward(curve) / span if span > 0 else float(values[0])


def final_performance(curve) -> float:
    return asymptotic_performance(curve, FINAL_TAIL)


def per_seed(runs: Sequence[Run], fn: Callable, metric: str = "team_return") -> dict[int, float]:
    return {r.seed: float(fn(r.curve(metric))) for r in runs}


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


# ================================================================================ report sections


@dataclass
class Section:
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


def _curves_figure(out: Path, name: str, panels: list[tuple[str, dict[str, list[Run]]]], title: str,
                   rng: np.random.Generator, note: str | None = None) -> Path:
    """Panels of learning curves (mean and 95% band per group); one panel per (metric, groups)."""
    fig, axes = plotting.plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 4.3), constrained_layout=True,
                                      squeeze=False)
    for ax, (metric, groups) in zip(axes[0], panels):
        for index, (label, runs) in enumerate(groups.items()):
            color = COLORS.get(label.split(" ")[-1].replace("transfer=", ""))
            plotting.plot_band(ax, [r.curve(metric) for r in runs], label, rng, color=color,
                               linestyle=plotting.LINESTYLES[index % len(plotting.LINESTYLES)])
        ax.set_xlabel("environment steps" + (f"\n{note}" if note else ""))
        ax.set_ylabel(f"eval {metric}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small", loc="lower right")
    fig.suptitle(title + " — mean, 95% bootstrap CI over seeds")
    path = _fig_path(out, name)
    fig.savefig(path, dpi=110)
    plotting.plt.close(fig)
    return path


def section_fig1(out: Path, runs: list[Run], rng: np.random.Generator) -> Section:
    by_mode = group(runs, lambda r: r.config["env"]["mode"])
    missing = [m for m in ("competitive", "cooperative") if m not in by_mode]
    claim = "1. One treasure: cooperation gives no advantage over competition"
    if missing:
        return Section(claim, _verdict("INCONCLUSIVE"), f"no {', '.join(missing)} runs", "", f"No {', '.join(missing)} runs in {out / 'fig1'}.")
    comp, coop = by_mode["competitive"], by_mode["cooperative"]
    sample = comp[0].config["env"]
    setting = (f"{comp[0].config['agent']['algorithm']} on a {sample.get('size')}x{sample.get('size')} map with "
               f"{sample.get('num_treasures')} treasure, {sample.get('num_traps')} trap(s) and "
               f"{team_size(comp[0].config, out)} agents")
    fig = _curves_figure(out, "fig1", [("team_return", {"competitive": comp, "cooperative": coop}),
                                       ("success_rate", {"competitive": comp, "cooperative": coop})],
                         "Figure 1: one treasure, competitive vs cooperative", rng)
    auc = {m: per_seed(g, mean_return_over_training) for m, g in (("competitive", comp), ("cooperative", coop))}
    fin = {m: per_seed(g, final_performance) for m, g in (("competitive", comp), ("cooperative", coop))}
    succ = {m: per_seed(g, final_performance, "success_rate") for m, g in (("competitive", comp), ("cooperative", coop))}
    d_auc = difference(auc["cooperative"], auc["competitive"], rng)
    d_fin = difference(fin["cooperative"], fin["competitive"], rng)
    d_succ = difference(succ["cooperative"], succ["competitive"], rng)
    steps, comp_mean, _, _ = plotting.curve_band([r.curve() for r in comp], rng, n_resamples=1)
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
        table.append(f"| {label} | {estimate(list(values['competitive'].values()), rng)} | "
                     f"{estimate(list(values['cooperative'].values()), rng)} | {diff} |")
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
    return diff("cooperative", "competitive"), diff("deliberative", "cooperative")


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
        "mean_return": {k: per_seed(g, mean_return_over_training) for k, g in cells.items()},
        "final_return": {k: per_seed(g, final_performance) for k, g in cells.items()},
        "final_success": {k: per_seed(g, final_performance, "success_rate") for k, g in cells.items()},
    }
    labels = {"mean_return": "mean eval team return over training (AUC / steps)",
              "final_return": f"final eval team return (last {FINAL_TAIL:.0%} of evals)",
              "final_success": f"final eval success rate (last {FINAL_TAIL:.0%})"}

    # Figure 2: each metric against team size, one line per mode (dodged so the error bars stay apart).
    fig, axes = plotting.plt.subplots(1, 3, figsize=(17, 4.5), constrained_layout=True)
    for ax, (name, values) in zip(axes, metrics.items()):
        for offset, mode, style in zip((-0.08, 0.0, 0.08), MODES, plotting.LINESTYLES):
            xs = [m for m in sizes if (mode, m) in values]
            if not xs:
                continue
            est = [estimate(list(values[(mode, m)].values()), rng) for m in xs]
            means = np.array([e.mean for e in est])
            lows = np.array([e.low if e.has_ci else e.mean for e in est])
            highs = np.array([e.high if e.has_ci else e.mean for e in est])
            n = "/".join(sorted({str(e.n) for e in est}))
            ax.errorbar(np.array(xs) + offset, means, yerr=[means - lows, highs - means], marker="o", capsize=4,
                        ls=style, label=f"{mode} (n={n})", color=COLORS[mode])
        ax.set_xticks(sizes)
        ax.set_xlabel("team size (agents, same map)")
        ax.set_ylabel(labels[name], fontsize="small")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle("Figure 2: complex map — performance vs team size (mean, 95% bootstrap CI over seeds)")
    fig2 = _fig_path(out, "fig2")
    fig.savefig(fig2, dpi=110)
    plotting.plt.close(fig)
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
    steps, mean, _, _ = plotting.curve_band([r.curve() for r in baseline], np.random.default_rng(0), n_resamples=1)
    final = asymptotic_performance((steps, mean), 0.1)
    low = float(mean.min())
    if final <= low:
        return None
    return low + THRESHOLD_FRACTION * (final - low)


def section_transfer(out: Path, runs: list[Run], rng: np.random.Generator) -> Section:
    claim = "3. Transfer from an already trained agent speeds up learning"
    cells = group(runs, lambda r: (r.config["agent"]["algorithm"], bool(r.config["transfer"]["enabled"])))
    algorithms = sorted({a for a, _ in cells}, key=lambda a: (a != "double_dqn", a))
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
        js = Estimate(**{k: results["jumpstart"][k] for k in ("mean", "low", "high", "n")})
        tr = Estimate(**{k: results["total_reward/difference"][k] for k in ("mean", "low", "high", "n")})
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
            "(jumpstart and transfer ratio against the mean baseline curve; `/difference` paired by seed; "
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
    groups = {k: v for k, v in cells.items()}
    evidence = f"{seeds_of(groups)} seeds per (learner, transfer); {describe_runs(runs)}"
    md = "\n".join([
        *(f"![Transfer learning curves]({f})\n" for f in figs),
        "\n\n".join(parts), "",
        f"Rule: {RULES['claim3']}", "",
        f"Verdict: {_verdict(overall)} — " + "; ".join(f"{a}: {v.lower()}" for a, v in verdicts.items()) + ".",
    ])
    return Section(claim, _verdict(overall), "; ".join(headlines) or "—", evidence, md, figs)


SECTIONS = {"fig1": section_fig1, "fig2": section_fig2, "transfer": section_transfer}


def _git_describe() -> str:
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return commit + (" (with uncommitted changes)" if dirty else "")


def write_report(out: Path, profile: str | None = None, seed: int = 0) -> Path:
    """Analyse ``OUT/{fig1,fig2,transfer}`` (whichever exist) into ``OUT/REPORT.md`` and PNG figures."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    sections, stamps = {}, {}
    for name in EXPERIMENTS:
        runs = load_runs(out / name)
        if not runs:
            continue
        stamp_path = out / name / "reproduce.json"
        stamps[name] = json.loads(stamp_path.read_text()) if stamp_path.exists() else {}
        try:
            sections[name] = SECTIONS[name](out, runs, rng)
        except (EvaluationError, ValueError, KeyError) as err:
            raise ReproduceError(f"cannot analyse {out / name}: {err}") from err
    if not sections:
        raise ReproduceError(f"{out} holds no runs of {', '.join(EXPERIMENTS)}: run the experiments first")
    profiles = {s.get("profile") for s in stamps.values()} - {None}
    if profile is not None:
        profiles.add(profile)
    smoke = "quick" in profiles
    lines = ["# Reproduction report: Transfer Learning Approach for Autonomous Agents in Collective Games", ""]
    if smoke:
        lines += [f"> **{PROFILES['quick'].description}** Run `python scripts/reproduce.py --profile full` "
                  "for evidence.", ""]
    lines += [f"Generated {_dt.datetime.now().isoformat(timespec='seconds')} from the runs under `{out}`; "
              f"profile: {', '.join(sorted(profiles)) or 'unknown'}; code: {_git_describe()}.", ""]
    walls = {n: s.get("wall_seconds") for n, s in stamps.items() if s.get("wall_seconds")}
    if walls:
        lines += ["Sweep wall times: " + ", ".join(f"{n} {w:.0f} s" for n, w in walls.items()) + ".", ""]
    lines += ["## Summary", "", "| claim | verdict | key numbers: mean [95% CI] | evidence |", "|---|---|---|---|"]
    for name in EXPERIMENTS:
        if name in sections:
            s = sections[name]
            lines.append(f"| {s.claim} | {s.verdict} | {s.headline} | {s.evidence} |")
        else:
            lines.append(f"| (experiment `{name}`) | not run | — | — |")
    lines += ["", "Verdicts follow the rules stated under each claim, fixed before looking at the data. A CI that "
              "contains 0 means no difference was detected with this many seeds, not that there is none. "
              "Intervals are 95% percentile bootstraps over seeds (10,000 resamples); differences between "
              "conditions pair runs of the same seed.", ""]
    if any(len(r) < 10 for r in (load_runs(out / n) for n in sections)) and not smoke:
        lines += ["> Some conditions rest on fewer than 10 seeds: treat their verdicts as preliminary.", ""]
    for name, s in sections.items():
        lines += [f"## Claim {s.claim}", "", s.markdown, ""]
    lines += ["## How to reproduce", "",
              "```bash",
              "python scripts/reproduce.py --profile quick --out /tmp/repro_quick   # smoke run, minutes",
              "python scripts/reproduce.py --profile full --out results             # evidence, ~30 min on 2 cores",
              "python scripts/reproduce.py --profile full --out results --launcher submitit_slurm \\",
              "    --extra hydra.launcher.partition=PART --extra hydra.launcher.timeout_min=120",
              "```", "",
              "The exact command of every sweep is the first line of `logs/<experiment>.log`; each run's "
              "config is in its `.hydra/` directory.", ""]
    report = out / "REPORT.md"
    report.write_text("\n".join(lines))
    return report


# ================================================================================ command line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    parser.add_argument("--profile", choices=sorted(PROFILES), default="quick")
    parser.add_argument("--out", type=Path, help="output directory (sweeps, figures, REPORT.md)")
    parser.add_argument("--only", default=",".join(EXPERIMENTS),
                        help=f"comma-separated subset of {','.join(EXPERIMENTS)} (default: all)")
    parser.add_argument("--launcher", default="joblib",
                        help="Hydra launcher: joblib (default), basic (one job at a time), submitit_slurm, ...")
    parser.add_argument("--n-jobs", type=int, default=2, help="parallel jobs with --launcher joblib (default 2)")
    parser.add_argument("--extra", action="append", default=[], metavar="OVERRIDE",
                        help="extra Hydra override for every sweep, e.g. hydra.launcher.partition=PART (repeatable)")
    parser.add_argument("--report-only", action="store_true", help="do not run anything; analyse OUT as it is")
    parser.add_argument("--write-maps", type=Path, metavar="DIR",
                        help="only write the Figure 2 team-size maps (fig2_m1..4.txt) into DIR")
    args = parser.parse_args(argv)
    try:
        if args.write_maps is not None:
            for path in write_team_maps(args.write_maps):
                print(path)
            return 0
        if args.out is None:
            parser.error("--out is required")
        only = [name.strip() for name in args.only.split(",") if name.strip()]
        unknown = [name for name in only if name not in EXPERIMENTS]
        if unknown:
            raise ReproduceError(f"--only: unknown experiment(s) {', '.join(unknown)} (choose from {', '.join(EXPERIMENTS)})")
        if args.n_jobs < 1:
            raise ReproduceError(f"--n-jobs must be >= 1, got {args.n_jobs}")
        out = args.out.expanduser().resolve()
        out.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        if not args.report_only:
            print(f"profile {args.profile}: {PROFILES[args.profile].description}", flush=True)
            for name in only:
                run_experiment(name, args.profile, out, args.launcher, args.n_jobs, args.extra)
        report = write_report(out, None if args.report_only else args.profile)
    except ReproduceError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print(f"wrote {report} ({time.perf_counter() - start:.0f} s in total)")
    for line in report.read_text().splitlines():
        if line.startswith("| ") and "**" in line:
            print("  " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
