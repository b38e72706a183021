"""Shared test helpers: running the ``python train.py`` command line in a subprocess.

The CLI tests call the real entry point, as a user would, so they cover Hydra's config handling,
the exit code and what lands on stdout/stderr. Each subprocess costs a few seconds of imports,
so tests reuse runs (module-scoped fixtures) and start independent runs side by side.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from safetensors import safe_open

from dqn_transfer.config import CONFIG_DIR, AgentConfig, TrainConfig, TransferConfig, register_configs, validate
from dqn_transfer.enums import Algorithm, Engine
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.exchange import check_exchange

REPO = Path(__file__).resolve().parent.parent
TRAIN_PY = REPO / "train.py"
TRAIN_TIMEOUT = 300  # seconds; a hung run fails the test instead of the suite


def train_env() -> dict[str, str]:
    """A fixed, quiet environment: fixed hash seed, one BLAS/OpenMP thread, no Hydra full traces.

    One thread keeps tiny networks fast when several runs share two cores, and keeps them
    reproducible. HYDRA_FULL_ERROR would turn Hydra's one-line errors into tracebacks.
    """
    env = dict(os.environ)
    env.pop("HYDRA_FULL_ERROR", None)
    env.update(PYTHONHASHSEED="0", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return env


def compose_config(*overrides: str) -> TrainConfig:
    """The :class:`TrainConfig` ``python train.py OVERRIDES`` composes (Hydra's ``compose``, no run)."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return OmegaConf.to_object(compose(config_name="config", overrides=list(overrides)))  # type: ignore[return-value]


def sweep_params(experiment: str) -> dict[str, list[str]]:
    """The options ``python train.py -m experiment=EXPERIMENT`` sweeps, by key (Hydra's sweeper params)."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        hydra = compose(config_name="config", overrides=[f"experiment={experiment}"], return_hydra_config=True).hydra
    return {key: str(value).split(",") for key, value in hydra.sweeper.params.items()}


def checked(config: TrainConfig) -> None:
    """What the run plan checks of ``config`` before any map: the schema, then every exchange method it runs."""
    validate(config)
    check_exchange(config)


def train_command(run_dir: Path, overrides: Iterable[str]) -> list[str]:
    return [sys.executable, str(TRAIN_PY), *overrides, "progress=false", f"hydra.run.dir={run_dir}"]


@dataclass
class TrainResult:
    """What one ``python train.py`` invocation left behind."""

    args: list[str]
    returncode: int
    stdout: str
    stderr: str
    run_dir: Path

    @property
    def output(self) -> str:
        return self.stdout + self.stderr

    def check(self) -> TrainResult:
        assert self.returncode == 0, (
            f"train.py {' '.join(self.args)} exited {self.returncode}\n"
            f"--- stdout\n{self.stdout}\n--- stderr\n{self.stderr}"
        )
        return self


def run_train(cwd: Path, *overrides: str, run_dir: Path | None = None, check: bool = True) -> TrainResult:
    """Run ``python train.py OVERRIDES progress=false hydra.run.dir=RUN_DIR`` with ``cwd`` as launch dir.

    ``run_dir`` defaults to ``cwd / "run"``; ``check`` asserts exit status 0 (with the output).
    """
    cwd = Path(cwd)
    run_dir = Path(run_dir) if run_dir is not None else cwd / "run"
    proc = subprocess.run(
        train_command(run_dir, overrides),
        cwd=cwd,
        env=train_env(),
        capture_output=True,
        text=True,
        timeout=TRAIN_TIMEOUT,
    )
    result = TrainResult(list(overrides), proc.returncode, proc.stdout, proc.stderr, run_dir)
    return result.check() if check else result


def start_train(cwd: Path, *overrides: str, run_dir: Path) -> subprocess.Popen:
    """Start a run in the background (e.g. to kill it); output goes to ``run_dir``'s sibling .out file."""
    with open(Path(run_dir).with_suffix(".out"), "w") as out:  # the child holds its own descriptor
        return subprocess.Popen(
            train_command(run_dir, overrides), cwd=cwd, env=train_env(), stdout=out, stderr=subprocess.STDOUT
        )


def run_many(jobs: Sequence[tuple[Path, Sequence[str], Path | None]], check: bool = True) -> list[TrainResult]:
    """Run independent ``(cwd, overrides, run_dir)`` jobs side by side, one per CPU core."""
    workers = max(2, min(len(jobs), os.cpu_count() or 2))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [
            pool.submit(run_train, cwd, *overrides, run_dir=run_dir, check=False) for cwd, overrides, run_dir in jobs
        ]
        results = [future.result() for future in futures]
    if check:
        for result in results:
            result.check()
    return results


def read_metrics(run_dir: Path) -> list[dict]:
    """The fully written lines of a run's ``metrics.jsonl`` (a live run's last line may be half-written)."""
    path = Path(run_dir) / "metrics.jsonl"
    text = path.read_text() if path.exists() else ""
    return [json.loads(line) for line in text.split("\n")[:-1] if line.strip()]


def without_timing(records: list[dict]) -> list[dict]:
    """Evaluation records without their wall-clock stamps: what same-seed runs must share."""
    return [{k: v for k, v in r.items() if k != "wall_time"} for r in records]


def agent_meta(path: Path) -> dict:
    """A checkpoint's meta, read with safetensors alone (no torch, no dqn_transfer)."""
    with safe_open(str(path), framework="numpy") as f:
        return json.loads(f.metadata()["meta"])


def reference_mlp(tensors: dict, prefix: str = "q"):
    """A plain ``nn.Sequential`` (Linear, ReLU, ..., Linear) from checkpoint tensors named
    ``{prefix}.layers.{l}.weight`` ``[out, in]`` / ``.bias``: the reference the learners and the
    transfer mapping are checked against, built without their code."""
    import torch
    from torch import nn

    num_layers = sum(1 for key in tensors if key.startswith(f"{prefix}.layers.") and key.endswith(".weight"))
    modules: list[nn.Module] = []
    for l in range(num_layers):
        weight = tensors[f"{prefix}.layers.{l}.weight"]
        linear = nn.Linear(weight.shape[1], weight.shape[0])
        with torch.no_grad():
            linear.weight.copy_(torch.as_tensor(weight))
            linear.bias.copy_(torch.as_tensor(tensors[f"{prefix}.layers.{l}.bias"]))
        modules.append(linear)
        if l < num_layers - 1:
            modules.append(nn.ReLU())
    return nn.Sequential(*modules)


@pytest.fixture(scope="session")
def train_cli():
    """The helpers above, for tests that prefer a fixture to an import."""
    return run_train


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    """In-process tests too: one intra-op thread (what the trainer uses by default, config `threads`)."""
    import torch

    torch.set_num_threads(1)


# Agent 0 at the top left, two steps left of a chest; agent 1 below it, facing the right edge.
ALWAYS_RIGHT_LAYOUT = "0.T\n1..\nX.."
UP, DOWN, LEFT, RIGHT = range(4)


def always_acting_team(run_dir: Path, action: int = RIGHT, layout: str = ALWAYS_RIGHT_LAYOUT) -> Path:
    """A finished run directory whose DQN agents always take ``action``: what a greedy episode does
    there is worked out by hand. Always right on the default layout: agent 0 takes the chest on step 2
    (-1 + 100) and agent 1 walks to the right edge and stays there until the 9th step truncates it
    (9 x -1): 9 steps, team return 90. The run is ``total_steps=0``; its agent files are then rewritten
    with zero weights and an output bias of 1 for ``action``, 0 for the others."""
    from dqn_transfer.config import AgentConfig, TrainConfig
    from dqn_transfer.envs.settings import EnvConfig
    from dqn_transfer.storage.checkpoint import load_agent_checkpoint, save_agent_checkpoint
    from dqn_transfer.storage.run_dir import RunDir
    from dqn_transfer.training.plan import plan_run
    from dqn_transfer.training.trainer import train

    env = EnvConfig(
        layout=layout,
        size=3,
        num_treasures=layout.count("T"),
        num_traps=layout.count("X"),
        num_agents=sum(ch.isdigit() for ch in layout),
        complexity=0.0,
    )
    train(
        plan_run(TrainConfig(env=env, agent=AgentConfig(algorithm="dqn", hidden=[8]), total_steps=0, progress=False)),
        run_dir,
    )
    for file in sorted(RunDir(run_dir).checkpoints.glob("agent_*.safetensors")):
        tensors, meta = load_agent_checkpoint(file)
        tensors = {name: np.zeros_like(t) for name, t in tensors.items()}
        for net in ("q", "target"):
            tensors[f"{net}.layers.1.bias"][action] = 1.0
        save_agent_checkpoint(
            file, tensors, {k: v for k, v in meta.items() if k not in ("format_version", "kind", "digest")}
        )
    return run_dir


def assert_named_paths_exist(output: str, root: Path) -> list[Path]:
    """Every path under ``root`` a run's output names exists after the run (no temp or ``.partial``
    directory renamed away meanwhile); returns them."""
    import re

    named = sorted({Path(p) for p in re.findall(rf"{re.escape(str(root))}[^\s;,`'\"]*", output)})
    assert named, output
    gone = [str(p) for p in named if not p.exists()]
    assert not gone, f"the output names paths that do not exist: {gone}"
    return named


def assert_one_error_line(main: Callable[[list[str]], int], argv: list[str], message: str, capsys) -> None:
    """``main(argv)`` exits 2 through its argument parser with one ``error:`` line starting with ``message``."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(message) and err.count("\n") == 1


# Warm-start tests on a hand-drawn 5x5 map with 2 agents and 2 chests: a tabular and a small numpy DQN learner.
WARM_START_QLEARNING = AgentConfig(algorithm=Algorithm.qlearning, lr=0.5)
WARM_START_NUMPY_DQN = AgentConfig(
    algorithm=Algorithm.dqn, engine=Engine.numpy, hidden=[16], batch_size=16, buffer_size=500, learning_starts=20
)
WARM_START_PRETRAIN_STEPS = 200


def warm_start_config(
    cache: Path, layout: str, num_traps: int, agent: AgentConfig, env: EnvConfig | None, **transfer
) -> TrainConfig:
    """A run of no steps of its own that warm-starts from sources pretrained into ``cache``, on the 5x5
    ``layout`` (or ``env``)."""
    env = env or EnvConfig(layout=layout, size=5, num_treasures=2, num_traps=num_traps, num_agents=2, complexity=0.0)
    return TrainConfig(
        env=env,
        agent=agent,
        seed=0,
        total_steps=0,
        eval_episodes=1,
        progress=False,
        transfer=TransferConfig(
            enabled=True, cache_dir=str(cache), pretrain_steps=WARM_START_PRETRAIN_STEPS, **transfer
        ),
    )


# Where a study report's text says its data are, in words true wherever it is written (--out copies no data).
REPORT_DATA = "Data: `data/` of the results directory from which `dqn-transfer-report RESULTS [--out DIR]` writes"
# What a study report says is beside it: its figures (markdown images) and any `PATH` "beside this report".
BESIDE_A_REPORT = re.compile(r"!\[[^\]]*\]\(([^)]+)\)|`([^`]+)` beside this report")


def missing_beside(report: Path) -> list[str]:
    """The relative paths the study report ``report`` says are beside it that are not there."""
    said = [image or text for image, text in BESIDE_A_REPORT.findall(report.read_text())]
    assert said, "the report names nothing beside it: the check would have no teeth"
    return [path for path in said if not (report.parent / path).exists()]
