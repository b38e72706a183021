#!/usr/bin/env python
"""Plot the evaluation curves of run directories: a person would rather look than read.

    python scripts/plot.py RUN_DIR [RUN_DIR ...] --out fig.png [--metric team_return]

A RUN_DIR is a Hydra run directory (it holds ``metrics.jsonl``) or any directory above some, e.g. a
multirun sweep directory: every run below it is used. Runs are grouped by what differs between their
configs (``.hydra/config.yaml``), ignoring the seed: each group is drawn as its mean over seeds with a
95% percentile-bootstrap band (one line when the group has one run). Runs without a readable config
get one line each. ``scripts/reproduce.py`` draws its figures with the same helpers.
"""

from __future__ import annotations

import argparse
import re
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: works on clusters and in CI without a display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # run as a file from anywhere, without installing the package
    sys.path.insert(0, str(ROOT))

from dqn_transfer.evaluation import METRICS_FILE, EvaluationError, learning_curve  # noqa: E402

Curve = tuple[np.ndarray, np.ndarray]
# Keys that differ between runs of one condition without making it another condition.
IGNORED_KEYS = ("seed", "progress", "resume", "device", "checkpoint_every", "transfer.cache_dir")
# Keys that name a condition, preferred as labels over what they imply (agent=sarsa implies agent.lr).
PRIMARY_KEYS = ("agent.algorithm", "env.mode", "transfer.enabled", "env.num_agents", "env.layout_file", "env.layout")
BAND_RESAMPLES = 2000


# ------------------------------------------------------------------------------------ run dirs


def _natural_key(path: Path) -> list:
    """Sort ``2`` before ``10`` (Hydra numbers multirun jobs)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", str(path))]


def find_run_dirs(paths: Sequence[str | Path]) -> list[Path]:
    """The run directories at or below ``paths`` (those holding ``metrics.jsonl``), naturally sorted."""
    runs: list[Path] = []
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise EvaluationError(f"{path}: no such directory")
        if (path / METRICS_FILE).is_file():
            runs.append(path)
            continue
        found = sorted((p.parent for p in path.rglob(METRICS_FILE)), key=_natural_key)
        if not found:
            raise EvaluationError(f"{path}: holds no run directory (no {METRICS_FILE} at or below it)")
        runs.extend(found)
    unique = list(dict.fromkeys(p.resolve() for p in runs))
    return unique


def load_config(run_dir: Path) -> dict[str, Any] | None:
    """The run's composed Hydra config (``.hydra/config.yaml``), or None if unreadable."""
    try:
        config = yaml.safe_load((Path(run_dir) / ".hydra" / "config.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return None
    return config if isinstance(config, dict) else None


def flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"env": {"mode": "x"}}`` -> ``{"env.mode": "x"}``; lists become tuples (hashable)."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flatten(value, name + "."))
        else:
            flat[name] = tuple(value) if isinstance(value, list) else value
    return flat


def _short(key: str, value: Any) -> str:
    if key.endswith("layout_file") and isinstance(value, str):
        value = Path(value).name
    if key == "transfer.enabled":
        return "transfer=" + ("on" if value else "off")
    return f"{key.split('.')[-1] if key.startswith(('env.', 'agent.')) else key}={value}"


def group_runs(run_dirs: Sequence[Path]) -> dict[str, list[Path]]:
    """Runs grouped by the config keys that differ between them (the seed excluded), labelled by them."""
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
    varying = chosen
    groups: dict[str, list[Path]] = {}
    for run, flat in zip(run_dirs, flats):
        label = ", ".join(_short(k, flat.get(k)) for k in varying) or "all runs"
        groups.setdefault(label, []).append(Path(run))
    return dict(sorted(groups.items()))  # sorted labels: transfer=off beside transfer=on


# ------------------------------------------------------------------------------------ statistics


def curve_band(curves: Sequence[Curve], rng: np.random.Generator, confidence: float = 0.95,
               n_resamples: int = BAND_RESAMPLES) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(steps, mean, low, high)`` over runs at the steps they all share; percentile bootstrap per step.

    With a single run the band collapses to the curve itself (there is no spread to resample).
    """
    common = curves[0][0]
    for steps, _ in curves[1:]:
        common = np.intersect1d(common, steps)
    if common.size == 0:
        raise EvaluationError("the runs share no evaluation step; cannot average their curves")
    values = np.stack([v[np.isin(s, common)] for s, v in curves])  # [runs, steps]
    mean = values.mean(axis=0)
    if values.shape[0] == 1:
        return common, mean, mean.copy(), mean.copy()
    idx = rng.integers(0, values.shape[0], size=(n_resamples, values.shape[0]))
    means = values[idx].mean(axis=1)  # [resamples, steps]
    low, high = np.quantile(means, [(1 - confidence) / 2, (1 + confidence) / 2], axis=0)
    return common, mean, low, high


LINESTYLES = ("-", "--", ":", "-.")


def plot_band(ax, curves: Sequence[Curve], label: str, rng: np.random.Generator, color=None,
              linestyle: str = "-") -> None:
    """Mean curve with its 95% CI band; the legend says how many runs it rests on."""
    steps, mean, low, high = curve_band(curves, rng)
    n = len(curves)
    line, = ax.plot(steps, mean, label=f"{label} (n={n})", color=color, lw=1.8, ls=linestyle)
    if n > 1:
        ax.fill_between(steps, low, high, color=line.get_color(), alpha=0.2, lw=0)


def plot_groups(groups: dict[str, list[Path]], metric: str, out: Path, title: str | None = None,
                seed: int = 0) -> Path:
    """One figure: every group's mean curve and band for ``metric``."""
    rng = np.random.default_rng(seed)
    fig, ax = plt.subplots(figsize=(7.5, 4.5), constrained_layout=True)
    for index, (label, dirs) in enumerate(groups.items()):  # line styles: identical curves stay visible
        plot_band(ax, [learning_curve(d, metric) for d in dirs], label, rng,
                  linestyle=LINESTYLES[index % len(LINESTYLES)])
    ax.set_xlabel("environment steps")
    ax.set_ylabel(f"eval {metric}")
    ax.set_title(title or f"eval {metric}: mean and 95% bootstrap CI over seeds")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="best")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories (or directories above them)")
    parser.add_argument("--out", required=True, type=Path, help="output image, e.g. fig.png")
    parser.add_argument("--metric", default="team_return",
                        help="metrics.jsonl key: team_return (default), success_rate, trap_rate, episode_length")
    parser.add_argument("--title", default=None)
    args = parser.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # incomplete last lines of running jobs
            run_dirs = find_run_dirs(args.runs)
            groups = group_runs(run_dirs)
            path = plot_groups(groups, args.metric, args.out, args.title)
    except (EvaluationError, ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    sizes = ", ".join(f"{label} ({len(d)})" for label, d in groups.items())
    print(f"wrote {path}: {len(run_dirs)} runs in {len(groups)} group(s): {sizes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
