"""A study edition as data: ``conf/edition/<name>.yaml`` says which experiments it runs, with which profiles,
through which stages, analysed and reported how; :mod:`~dqn_transfer.experiments.pipeline` runs any of them.

A results directory records its edition in ``data/manifest.json`` (``edition``), so that
``dqn-transfer-report DIR`` knows which analysis wrote it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import reduce
from pathlib import Path
from typing import Any

import yaml

from dqn_transfer.analysis.budget import BudgetRule
from dqn_transfer.config import CONFIG_DIR
from dqn_transfer.experiments.raw_data import DATA_DIR, read_manifest
from dqn_transfer.experiments.sweeps import ReproduceError

EDITIONS_DIR = CONFIG_DIR / "edition"
# A results directory beside its data/: what the tuning, pilot and budget stages write, which the report reads.
TUNING_DIR, PILOT_DIR, BUDGETS_FILE, BUDGETS_TABLE = "tuning", "pilot", "budgets.json", "budgets.md"
STAGES = ("tune", "pilot", "full", "report")
# The first edition's claims, the second's hierarchical bootstrap, the third's outcomes against the SESOI.
ANALYSES = ("paired", "hierarchical", "equivalence")
MAPS_FILE, MAPS_TABLE = "maps.json", "maps.md"  # the power rule's maps per cell (an edition with cells)
STAGES_FILE = "stages.json"  # each stage's attempts' wall seconds, which the report states
# Every stage run again into another directory: its stage times, code, date and machine and its run records'
# digest, which the report states beside the first execution's (pipeline.record_repeat).
REPEAT_FILE = "repeat.json"


@dataclass(frozen=True)
class Profile:
    """How much a stage runs: the pilot's overrides, the runs' (every experiment's, then one's own), and the
    budget rule's cap for the pilot (None: the edition's rule)."""

    description: str
    pilot: tuple[str, ...] = ()
    runs: tuple[str, ...] = ()
    runs_of: dict[str, tuple[str, ...]] = field(default_factory=dict)
    rule_cap: int | None = None
    pilot_maps: int | None = None  # an edition with cells: its pilot's maps (None: the edition's)
    minimum: int | None = None  # an edition with cells: every cell's fewest maps (None: each cell's own)
    cap: int | None = None  # an edition with cells: every cell's most maps (None: each cell's own)

    def run_overrides(self, experiment: str) -> tuple[str, ...]:
        """The overrides of ``experiment``'s runs under this profile."""
        return (*self.runs, *self.runs_of.get(experiment, ()))


@dataclass(frozen=True)
class Comparison:
    """Which of an experiment's jobs share a budget: those alike in :attr:`keys` (dotted config keys)."""

    name: str  # the comparison (transfer and transfer_aware are one: their conditions are compared)
    keys: tuple[str, ...]

    def key(self, config: dict[str, Any]) -> tuple[Any, ...]:
        """A job's group: its values of :attr:`keys`."""
        return tuple(reduce(lambda node, part: node[part], dotted.split("."), config) for dotted in self.keys)


@dataclass(frozen=True)
class TuningCell:
    """One game's tuning: its searches (``conf/experiment/tune/<learner>_<method>``), each run with
    ``overrides``, into ``OUT/tuning/<name>/`` (``OUT/tuning/`` for an unnamed one)."""

    name: str
    searches: tuple[str, ...]
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class Cell:
    """A cell of the main hypothesis: the jobs of ``experiment`` whose swept values include ``where``, each
    condition (its ``method``) at its values tuned in ``tuning``, on between ``minimum`` and ``cap`` maps."""

    name: str
    experiment: str
    tuning: str
    minimum: int
    cap: int
    where: dict[str, str] = field(default_factory=dict)

    def holds(self, experiment: str, values: dict[str, str]) -> bool:
        """Whether a job of ``experiment`` with swept ``values`` is one of this cell's conditions."""
        return experiment == self.experiment and all(values.get(k) == v for k, v in self.where.items())


@dataclass(frozen=True)
class Edition:
    """One edition of the study (``conf/edition/<name>.yaml``)."""

    name: str
    title: str  # the report's heading
    results: str  # where its evidence is committed, e.g. results/v2
    rules: str  # its verdict rules, as the report names them
    experiment_group: str  # conf/experiment/<group>/<name>.yaml ("" for conf/experiment/<name>.yaml)
    experiments: tuple[str, ...]
    stages: tuple[str, ...]
    analysis: str
    profiles: dict[str, Profile]
    caches: dict[str, tuple[str, str]] = field(default_factory=dict)  # experiment: (config key, OUT's subdirectory)
    rules_tag: str | None = None  # the git tag or commit that registered the rules (None: the rules file's last commit)
    rule: BudgetRule | None = None  # the budget rule of the pilot stage
    comparisons: dict[str, Comparison] = field(default_factory=dict)
    report: dict[str, Any] = field(default_factory=dict)  # the report's text that is the edition's own
    tuning: tuple[TuningCell, ...] = ()  # the tune stage's searches by game
    trials_per_dimension: int | None = None  # a search's trials per searched key (None: its file's n_trials)
    cells: tuple[Cell, ...] = ()  # the main hypothesis' cells (an equivalence edition)
    pilot_maps: int = 0  # a cell's pilot: its first maps, 0 .. pilot_maps - 1
    tuned_as: dict[str, str] = field(default_factory=dict)  # a control: the method whose tuned values it runs at
    chunk_gigabytes: float | None = None  # a cell's multirun's estimated peak memory at most (None: no bound)

    def experiment(self, name: str) -> str:
        """The ``experiment=`` option of one of its experiments."""
        return f"{self.experiment_group}/{name}" if self.experiment_group else name

    def profile(self, name: str) -> Profile:
        if name not in self.profiles:
            raise ReproduceError(
                f"edition {self.name} has no profile {name!r} (choose from {', '.join(self.profiles)})"
            )
        return self.profiles[name]

    def check_stage(self, stage: str) -> None:
        """Refuse a stage the edition does not have."""
        if stage not in self.stages:
            raise ReproduceError(f"edition {self.name} has no {stage} stage (its stages: {', '.join(self.stages)})")


def edition_names() -> list[str]:
    """The editions ``conf/edition/`` describes."""
    return sorted(path.stem for path in EDITIONS_DIR.glob("*.yaml"))


def load_edition(name: str) -> Edition:
    """The edition ``conf/edition/<name>.yaml``; a :class:`ReproduceError` for an unknown or malformed one."""
    path = EDITIONS_DIR / f"{name}.yaml"
    if not path.is_file():
        raise ReproduceError(f"no edition {name!r} (choose from {', '.join(edition_names())})")
    spec = yaml.safe_load(path.read_text())
    try:
        profiles = {
            key: Profile(
                description=value["description"],
                pilot=tuple(value.get("pilot", ())),
                runs=tuple(value.get("runs", ())),
                runs_of={experiment: tuple(o) for experiment, o in value.get("runs_of", {}).items()},
                rule_cap=value.get("rule_cap"),
                pilot_maps=value.get("pilot_maps"),
                minimum=value.get("minimum"),
                cap=value.get("cap"),
            )
            for key, value in spec.pop("profiles").items()
        }
        comparisons = {
            experiment: Comparison(value.get("name", experiment), tuple(value["keys"]))
            for experiment, value in spec.pop("comparisons", {}).items()
        }
        rule = spec.pop("rule", None)
        tuning = spec.pop("tuning", {})
        edition = Edition(
            tuning=tuple(
                TuningCell(name, tuple(cell["searches"]), tuple(cell.get("overrides", ())))
                for name, cell in tuning.get("cells", {}).items()
            ),
            trials_per_dimension=tuning.get("trials_per_dimension"),
            cells=tuple(Cell(name=name, **cell) for name, cell in spec.pop("cells", {}).items()),
            name=name,
            profiles=profiles,
            comparisons=comparisons,
            rule=None if rule is None else BudgetRule(**rule),
            experiments=tuple(spec.pop("experiments")),
            stages=tuple(spec.pop("stages")),
            caches={experiment: (key, subdir) for experiment, (key, subdir) in spec.pop("caches", {}).items()},
            **spec,
        )
    except (KeyError, TypeError, ValueError) as err:
        raise ReproduceError(f"{path}: not an edition ({err!r})") from err
    if edition.analysis not in ANALYSES or not set(edition.stages) <= set(STAGES):
        raise ReproduceError(f"{path}: analysis one of {', '.join(ANALYSES)}, stages among {', '.join(STAGES)}")
    return edition


def edition_of(results: Path, named: str | None = None) -> Edition:
    """The edition whose report ``results`` holds: ``named``, else the one its manifest records.

    :param results: a results directory (``data/``, and what its stages wrote beside it)
    :param named: the edition given on the command line (None: the manifest's)
    """
    name = named or read_manifest(results / DATA_DIR).get("edition")
    if name is None:
        raise ReproduceError(
            f"{results / DATA_DIR / 'manifest.json'} names no edition: pass --edition ({', '.join(edition_names())})"
        )
    return load_edition(str(name))
