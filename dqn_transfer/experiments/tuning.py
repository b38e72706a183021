"""The fair tuning protocol (docs/tuning.md): one Optuna search per learner x knowledge-exchange method.

Each search (``conf/experiment/tune/<learner>_<method>``) is one Hydra multirun with the Optuna sweeper; its
trials are read back from their run directories into ``OUT/tuning.jsonl``, from which alone :func:`analyse`
writes the tuned values, the table and the figure.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import IntervalSweep
from hydra.errors import HydraException

from dqn_transfer.analysis.plots import dose_response_figure
from dqn_transfer.analysis.runs import EvaluationError, load_config, run_objective
from dqn_transfer.analysis.tuning import (
    Interval,
    Trial,
    TuningError,
    best_trials,
    check_searches,
    read_trials,
    sensitivity_panels,
    trial_from_record,
    tuned_yaml,
    tuning_table,
    write_trials,
)
from dqn_transfer.config import CONFIG_DIR
from dqn_transfer.experiments.render import COLORS
from dqn_transfer.experiments.sweeps import RUNS_DIR, Multirun, composed, job_dirs, run_multirun
from dqn_transfer.storage.run_dir import RunDir

TRIALS_FILE, TUNED_FILE, TABLE_FILE, FIGURE_FILE = "tuning.jsonl", "tuned.yaml", "tuning.md", "tuning_sensitivity.png"
TUNE_GROUP = "tune"  # conf/experiment/tune/
TUNED_GROUP = "tuned"  # conf/tuned/<learner>_<method>.yaml: the chosen values, which conf/method/ composes
# The quick profile: two trials of tiny runs on two tuning maps per search, to check the pipeline (not
# evidence: 300 steps teach a team next to nothing).
PROFILES: dict[str, tuple[str, ...]] = {
    "quick": (
        "hydra.sweeper.n_trials=2",
        "total_steps=300",
        "eval_every=150",
        "eval_episodes=2",
        "replicas.maps=2",
        "agent.learning_starts=100",
    ),
    "full": (),  # tune/base.yaml's own settings
}
# One trial's seconds at the full profile (8,000 steps x 10 maps, one core, measured 2026-12-03: docs/tuning.md),
# used only to start the longest searches first (its ratio matters, not its scale).
TRIAL_SECONDS = {"sarsa": 6.0, "double_dqn": 20.0}


@dataclass(frozen=True)
class Search:
    """One learner x knowledge-exchange method, searched by the experiment config ``tune/<name>``."""

    learner: str
    method: str

    @property
    def name(self) -> str:
        return f"{self.learner}_{self.method}"

    @property
    def experiment(self) -> str:
        return f"{TUNE_GROUP}/{self.name}"


SEARCHES = tuple(Search("sarsa", m) for m in ("none", "best", "shared_replay", "confidence", "advice")) + tuple(
    Search("double_dqn", m) for m in ("none", "best", "shared_replay", "experience", "shared_id", "vdn")
)


def search_named(name: str) -> Search:
    for search in SEARCHES:
        if search.name == name:
            return search
    raise TuningError(f"unknown search {name!r} (choose from {', '.join(s.name for s in SEARCHES)})")


def search_multiruns(
    searches: Sequence[Search],
    overrides: Sequence[str],
    out: Path,
    trials_per_dimension: int | None = None,
) -> list[Multirun]:
    """Each search as one multirun into ``OUT/runs/<name>`` (what :func:`run_searches` runs).

    :param overrides: every search's settings (a profile's, an edition's tuning cell's)
    :param trials_per_dimension: the trials of a search per searched key (None: the search file's n_trials);
        ``overrides`` may still set ``hydra.sweeper.n_trials`` (the quick profile does)
    """
    multiruns = []
    for search in searches:
        own = list(overrides)
        if trials_per_dimension is not None:
            dimensions = len(composed(search.experiment, hydra_config=True).hydra.sweeper.params)
            own.insert(0, f"hydra.sweeper.n_trials={trials_per_dimension * dimensions}")
        trials = int(composed(search.experiment, own, hydra_config=True).hydra.sweeper.n_trials)
        stamp = {"search": search.name, "overrides": own, "jobs": trials}
        multiruns.append(
            Multirun(search.name, search.experiment, tuple(own), out / RUNS_DIR / search.name, trials, stamp)
        )
    return multiruns


def expected_seconds(multirun: Multirun) -> float:
    """A search's trials times one trial's seconds (:data:`TRIAL_SECONDS`)."""
    return multirun.jobs * TRIAL_SECONDS.get(search_named(multirun.stamp["search"]).learner, 0.0)


def run_searches(multiruns: Sequence[tuple[Multirun, Path]], parallel: int, poll_seconds: float = 2.0) -> None:
    """Searches' multiruns, each with its tuning directory (where its log goes), ``parallel`` at once, the
    longest first (:func:`expected_seconds`), so that the last to start are short and no core waits long
    at the end; a search finished before with the same settings is reused. Raises the first failure's
    :class:`~dqn_transfer.experiments.sweeps.ReproduceError` once every search has ended."""
    longest_first = sorted(multiruns, key=lambda planned: -expected_seconds(planned[0]))
    with ThreadPoolExecutor(max_workers=parallel) as pool:
        futures = [pool.submit(run_multirun, m, out, "basic", 1, (), poll_seconds) for m, out in longest_first]
    for future in futures:
        future.result()


def _space(params: dict[str, str], where: Path) -> dict[str, Interval]:
    """A search's ``hydra.sweeper.params`` as intervals (the protocol searches ranges only)."""
    parser = OverridesParser.create()
    space = {}
    for key, spec in params.items():
        value = parser.parse_override(f"{key}={spec}").value()
        if not isinstance(value, IntervalSweep) or value.start is None or value.end is None:
            raise TuningError(f"{where}: {key}={spec} is not an interval; the protocol searches ranges only")
        space[key] = Interval(float(value.start), float(value.end), "log" in value.tags)
    return space


def read_trial(search: Search, job_dir: Path) -> Trial:
    """A finished trial from its job directory: its searched values from ``.hydra/overrides.yaml``, its
    objective from its replicas' ``metrics.jsonl`` (as the sweeper got it), each map's alone."""
    files = RunDir(job_dir)
    hydra_config = yaml.safe_load((files.hydra_dir / "hydra.yaml").read_text())
    space = _space(dict(hydra_config["hydra"]["sweeper"]["params"]), job_dir)
    overrides = OverridesParser.create().parse_overrides(yaml.safe_load(files.overrides.read_text()))
    params: dict[str, float] = {}
    for override in overrides:
        key, value = override.get_key_element(), override.value()
        if key in space:
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise TuningError(f"{job_dir}: {key}={value!r} is not a number")
            params[key] = value
    kind = str((load_config(job_dir) or {}).get("objective"))
    by_map: dict[int, list[float]] = {}
    for replica in files.replica_dirs() or [job_dir]:
        seed = int((load_config(replica) or {})["env"]["map_seed"])
        by_map.setdefault(seed, []).append(run_objective(replica, kind))
    per_map = {seed: sum(values) / len(values) for seed, values in sorted(by_map.items())}
    objective = run_objective(job_dir, kind)
    trial = Trial(search.learner, search.method, int(job_dir.name), params, objective, kind, per_map, space)
    return trial_from_record(trial.record(), str(job_dir))  # the checks a trial read from tuning.jsonl passes


def collect_trials(searches: Sequence[Search], out: Path) -> list[Trial]:
    """Every trial of ``searches`` from ``OUT/runs/``, checked against each search's own record of its best
    value (``optimization_results.yaml``)."""
    trials: list[Trial] = []
    for search in searches:
        sweep_dir = out / RUNS_DIR / search.name
        jobs = job_dirs(sweep_dir)
        if not jobs:
            raise TuningError(f"{sweep_dir}: no trials of search {search.name} (run it first)")
        try:
            found = [read_trial(search, job) for job in jobs]
            recorded = yaml.safe_load((sweep_dir / "optimization_results.yaml").read_text())["best_value"]
        except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError, HydraException, EvaluationError) as err:
            raise TuningError(f"{sweep_dir}: not a finished search ({err})") from None
        if abs(max(t.objective for t in found) - float(recorded)) > 1e-9 * max(1.0, abs(float(recorded))):
            raise TuningError(f"{sweep_dir}: its trials' best objective is not the sweeper's best_value {recorded}")
        trials += found
    check_searches(trials, str(out / RUNS_DIR))
    return trials


def analyse(out: Path) -> list[Path]:
    """``tuned.yaml``, ``tuning.md`` and ``tuning_sensitivity.png`` in ``OUT`` from ``OUT/tuning.jsonl``
    alone; nothing is written if it cannot be read."""
    trials = read_trials(out / TRIALS_FILE)
    best = best_trials(trials)
    table, tuned = tuning_table(trials, best), tuned_yaml(best)
    figure = dose_response_figure(
        out / FIGURE_FILE,
        sensitivity_panels(trials, best),
        "Tuning: objective against each searched value (the best trial of each search starred)",
        f"{trials[0].objective_kind} team return (tuning maps)",
        COLORS.get,
    )
    (out / TUNED_FILE).write_text(tuned)
    (out / TABLE_FILE).write_text(table)
    return [out / TRIALS_FILE, out / TUNED_FILE, out / TABLE_FILE, figure]


def tune(
    cells: Sequence[tuple[Sequence[Search], Sequence[str], Path]],
    parallel: int,
    trials_per_dimension: int | None = None,
) -> list[Path]:
    """Every tuning cell's searches (``(searches, overrides, out)`` each) in one pool (:func:`run_searches`),
    then each cell's trials collected into its ``OUT/tuning.jsonl`` and analysed."""
    planned = []
    for searches, overrides, out in cells:
        out.mkdir(parents=True, exist_ok=True)
        planned += [(multirun, out) for multirun in search_multiruns(searches, overrides, out, trials_per_dimension)]
    run_searches(planned, parallel)
    written: list[Path] = []
    for searches, _, out in cells:
        write_trials(out / TRIALS_FILE, collect_trials(searches, out))
        written += analyse(out)
    return written


def tuned_options(tuned: dict[str, dict[str, dict[str, Any]]]) -> dict[str, str]:
    """The text of each ``conf/tuned/<learner>_<method>.yaml`` from ``tuned.yaml``'s tree (learner -> method
    -> dotted key -> value): the values as a config's nested keys."""
    options = {}
    for learner, methods in tuned.items():
        for method, params in methods.items():
            tree: dict[str, Any] = {}
            for key, value in params.items():
                *groups, leaf = key.split(".")
                node = tree
                for group in groups:
                    node = node.setdefault(group, {})
                node[leaf] = value
            options[f"{learner}_{method}"] = (
                "# @package _global_\n"
                f"# {learner} x {method}: the values the tuning chose (the study's second edition, stage 2:\n"
                "# results/v2/tuning/tuned.yaml, written here by cli.study tune --apply).\n"
                + yaml.safe_dump(tree, sort_keys=True)
            )
    return options


def apply_tuned(out: Path, conf_dir: Path = CONFIG_DIR) -> list[Path]:
    """Write ``OUT/tuned.yaml``'s values as ``conf_dir/tuned/<learner>_<method>.yaml``, each file whole; the
    methods (``conf/method/<learner>_<method>.yaml``) compose them."""
    path = out / TUNED_FILE
    try:
        tuned = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise TuningError(f"{path}: cannot read the tuned values ({err})") from None
    if not isinstance(tuned, dict):
        raise TuningError(f"{path}: not a tuned.yaml (learner -> method -> values)")
    written = []
    for name, text in tuned_options(tuned).items():
        target = conf_dir / TUNED_GROUP / f"{name}.yaml"
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
        written.append(target)
    return written
