"""The distributed engine, verified: a two-job sweep through Hydra's submitit launcher.

``hydra/launcher=submitit_local`` is the plugin that runs sweeps on SLURM (``submitit_slurm``, from
hydra-submitit-launcher) with local processes in place of SLURM jobs: the launching process pickles
the app and each job's overrides into submitit's folder, one ``python -m submitit.core._submit``
process per job unpickles and runs it, and the launcher waits for their results. So this checks what
a SLURM sweep needs besides SLURM itself: that the app survives the trip through the pickle, that each
job claims and fills its own run directory, and that the sweep exits 0 only when every job did.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import REPO, TRAIN_PY, TRAIN_TIMEOUT, agent_meta, read_metrics, train_env, without_timing

pytestmark = pytest.mark.slow  # starts `python train.py -m` and, through submitit, one process per job

MAP = "0...T\n.#...\n...#.\nX....\n1..T.\n"  # 5 x 5, two chests, one trap, two agents ("0", "1")
NUM_AGENTS = 2
# The map's own parameters, so that the layout file overrides nothing (no warning in the logs).
ENV = (
    "env.layout_file=map.txt",
    "env.size=5",
    "env.num_treasures=2",
    "env.num_traps=1",
    "env.num_agents=2",
    "env.complexity=0.08",
    "env.map_seed=0",
)
SEEDS = (0, 1)
TOTAL_STEPS, EVAL_EVERY = 300, 100
# submitit's local controller sends the job its "about to time out" signal (SIGUSR2) 30 s before
# timeout_min, and submitit then requeues the job from the start: at timeout_min=1 that would come
# 30 s into a job on a busy machine. 3 minutes leaves the jobs (a few seconds each) far from it, and
# the controller, which outlives a killed launcher, still ends a hung job before TRAIN_TIMEOUT.
TIMEOUT_MIN = 3
assert TIMEOUT_MIN * 60 < TRAIN_TIMEOUT


def sweep_command(sweep_dir: Path) -> list[str]:
    return [
        sys.executable,
        str(TRAIN_PY),
        "-m",
        "hydra/launcher=submitit_local",
        f"hydra.launcher.timeout_min={TIMEOUT_MIN}",
        "hydra.launcher.cpus_per_task=1",
        f"seed={','.join(map(str, SEEDS))}",
        *ENV,
        "agent=sarsa",
        f"total_steps={TOTAL_STEPS}",
        f"eval_every={EVAL_EVERY}",
        f"checkpoint_every={EVAL_EVERY}",
        "eval_episodes=2",
        "progress=false",
        f"hydra.sweep.dir={sweep_dir}",
    ]


def sweep_env() -> dict[str, str]:
    """train_env(), with this checkout first on the path of the job processes too: they import
    dqn_transfer afresh (``python -m submitit.core._submit`` in the launch directory), and must run the
    same code as the launching ``train.py``, which finds it beside itself."""
    env = train_env()
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def run_sweep(launch: Path, sweep_dir: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        sweep_command(sweep_dir), cwd=launch, env=sweep_env(), capture_output=True, text=True, timeout=TRAIN_TIMEOUT
    )


def submitit_jobs(sweep_dir: Path) -> list[Path]:
    """submitit's per-job log folders (``.submitit/<job id>``; it also leaves an empty ``%j``, its
    folder template, which is no job)."""
    folder = sweep_dir / ".submitit"
    return sorted(p for p in folder.iterdir() if p.is_dir() and p.name != "%j") if folder.is_dir() else []


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    launch = tmp_path_factory.mktemp("submitit")
    (launch / "map.txt").write_text(MAP)
    sweep_dir = launch / "sweep"
    result = run_sweep(launch, sweep_dir)
    assert result.returncode == 0, f"--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    return launch, sweep_dir


def job_dirs(sweep_dir: Path) -> dict[int, Path]:
    """The sweep's run directories, by the seed their recorded config says."""
    dirs = [d for d in sweep_dir.iterdir() if (d / ".hydra" / "config.yaml").is_file()]
    by_seed = {yaml.safe_load((d / ".hydra" / "config.yaml").read_text())["seed"]: d for d in dirs}
    assert len(by_seed) == len(dirs), f"two jobs ran the same seed: {dirs}"
    return by_seed


def test_each_job_of_a_submitit_sweep_fills_its_own_run_directory(sweep):
    _, sweep_dir = sweep
    jobs = job_dirs(sweep_dir)
    assert sorted(jobs) == list(SEEDS)
    assert sorted(d.name for d in jobs.values()) == [str(n) for n in range(len(SEEDS))]  # hydra.sweep.subdir
    assert (sweep_dir / "multirun.yaml").is_file()

    expected_steps = list(range(0, TOTAL_STEPS + 1, EVAL_EVERY))  # TOTAL_STEPS is on the grid
    for seed, d in jobs.items():
        assert f"seed={seed}" in yaml.safe_load((d / ".hydra" / "overrides.yaml").read_text())
        config = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
        assert config["total_steps"] == TOTAL_STEPS and config["agent"]["algorithm"] == "sarsa"

        text = (d / "metrics.jsonl").read_text()
        assert text.endswith("\n"), "the last metrics line is incomplete"
        metrics = read_metrics(d)
        assert [m["step"] for m in metrics] == expected_steps
        assert metrics[-1]["step"] == TOTAL_STEPS

        checkpoints = d / "checkpoints"
        assert (checkpoints / "training_state.safetensors").is_file()
        for i in range(NUM_AGENTS):
            meta = agent_meta(checkpoints / f"agent_{i}.safetensors")
            assert meta["steps"] == TOTAL_STEPS and meta["algorithm"] == "sarsa"
        assert not (checkpoints / f"agent_{NUM_AGENTS}.safetensors").exists()
        assert list((d / "tb").glob("events.out.tfevents.*"))

    # Different seeds: different runs (not one job's results copied, nor one seed run twice).
    assert without_timing(read_metrics(jobs[0])) != without_timing(read_metrics(jobs[1]))

    # submitit's own records: one folder per job, with its log and the result it sent back.
    logs = submitit_jobs(sweep_dir)
    assert len(logs) == len(SEEDS), logs
    for folder in logs:
        assert list(folder.glob("*_log.out")) and list(folder.glob("*_result.pkl")), sorted(folder.iterdir())


def test_the_same_sweep_again_is_refused_before_any_job_is_submitted(sweep):
    launch, sweep_dir = sweep
    records = {d: (d / ".hydra" / "config.yaml").read_bytes() for d in job_dirs(sweep_dir).values()}
    before = submitit_jobs(sweep_dir)
    again = run_sweep(launch, sweep_dir)
    assert again.returncode == 1 and "Traceback" not in again.stdout + again.stderr, again.stderr
    assert f"error: {sweep_dir} already holds the runs of a sweep (0, 1)" in again.stderr
    assert submitit_jobs(sweep_dir) == before  # refused in the launching process: nothing was submitted
    assert {d: (d / ".hydra" / "config.yaml").read_bytes() for d in records} == records
