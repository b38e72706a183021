"""`python train.py -m hydra/sweeper=optuna ...`: Hydra's Optuna sweeper searches schema keys, each trial a
run of replicas (its seeds), and optimises the run's ``objective`` (docs/integrations.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import TRAIN_PY, TRAIN_TIMEOUT, train_env

pytest.importorskip("hydra_plugins.hydra_optuna_sweeper", reason="the optuna extra: pip install -e '.[optuna]'")

pytestmark = pytest.mark.slow  # a tiny search: three `python train.py` trials in one process

TRIALS, SEEDS = 3, 2


def objective_of(trial_dir: Path, objective: str) -> float:
    """The trial's objective from its replicas' metrics.jsonl, independently of the package's reader."""
    replicas = json.loads((trial_dir / "replicas.json").read_text())["replicas"]
    assert len(replicas) == SEEDS
    per_replica = []
    for name in replicas:
        lines = (trial_dir / name / "metrics.jsonl").read_text().splitlines()
        returns = [json.loads(line)["team_return"] for line in lines if line.strip()]
        per_replica.append(returns[-1] if objective == "final" else float(np.mean(returns)))
    return float(np.mean(per_replica))


@pytest.mark.parametrize("objective", ["mean"])
def test_a_tiny_optuna_search_reports_its_best_trial(tmp_path, objective):
    sweep_dir = tmp_path / "search"
    command = [
        sys.executable,
        str(TRAIN_PY),
        "-m",
        "hydra/sweeper=optuna",
        "hydra.sweeper.direction=maximize",
        f"hydra.sweeper.n_trials={TRIALS}",
        "hydra.sweeper.n_jobs=1",
        "hydra.sweeper.sampler.seed=0",
        "agent.lr=tag(log, interval(1e-4, 1e-1))",
        f"replicas.seeds={SEEDS}",
        f"objective={objective}",
        "total_steps=100",
        "eval_every=50",
        "eval_episodes=2",
        "agent.learning_starts=10",
        "progress=false",
        f"hydra.sweep.dir={sweep_dir}",
    ]
    proc = subprocess.run(command, cwd=tmp_path, env=train_env(), capture_output=True, text=True, timeout=TRAIN_TIMEOUT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    results = yaml.safe_load((sweep_dir / "optimization_results.yaml").read_text())
    trials = sorted((d for d in sweep_dir.iterdir() if d.is_dir() and d.name.isdigit()), key=lambda d: int(d.name))
    assert len(trials) == TRIALS
    values = {d: objective_of(d, objective) for d in trials}
    best = max(values, key=values.__getitem__)
    assert results["best_value"] == pytest.approx(values[best], abs=1e-9)
    overrides = yaml.safe_load((best / ".hydra" / "overrides.yaml").read_text())
    lr = next(float(o.split("=", 1)[1]) for o in overrides if o.startswith("agent.lr="))
    assert results["best_params"]["agent.lr"] == pytest.approx(lr)
    lrs = {float(yaml.safe_load((d / ".hydra" / "config.yaml").read_text())["agent"]["lr"]) for d in trials}
    assert len(lrs) == TRIALS and all(1e-4 <= lr <= 1e-1 for lr in lrs)  # the searched key, in its interval
