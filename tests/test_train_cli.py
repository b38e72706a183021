"""End-to-end tests of ``python train.py``: the files a run leaves behind, the
TensorBoard tags, self-describing checkpoints, reproducibility, resume after SIGKILL, and the
one-line refusal of bad input.

Runs are tiny (a 5 x 5 map, a few hundred steps) and shared between tests through module-scoped
fixtures; independent runs go side by side (see ``conftest.run_many``).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, agent_meta, read_metrics, run_many, run_train, start_train, train_env, without_timing

pytestmark = pytest.mark.slow  # every test here starts `python train.py` processes or trains for seconds

# 5 x 5, two chests (row 0 col 4; row 4 col 3), one trap (row 3 col 0), two obstacles, two agents.
# The trap is two cells away from any chest, so the map obeys the map rules (docs/game.md).
MAP = "0...T\n.#...\n...#.\nX....\n1..T.\n"
SIZE, NUM_AGENTS, NUM_TREASURES = 5, 2, 2

BASE = ("env.layout_file=map.txt", "eval_episodes=2")
SMALL_NET = ("agent.hidden=[32]", "agent.batch_size=32", "agent.target_update=100", "agent.tau=1.0")

# One run per learner, each in a different mode; (overrides, total_steps, eval_every).
LEARNER_RUNS = {
    "sarsa": (("agent=sarsa", "mode=competitive"), 300, 100),
    "qlearning": (("agent=qlearning", "mode=cooperative"), 250, 100),  # last eval off the grid
    "dqn": (("agent=dqn", "mode=deliberative", "agent.learning_starts=50", *SMALL_NET), 400, 100),
    "double_dqn": (("agent=double_dqn", "mode=cooperative", "agent.learning_starts=50", *SMALL_NET), 300, 150),
}

TB_TAGS = [
    f"agent_{i}/{name}"
    for i in range(NUM_AGENTS)
    for name in ("episodic_return", "episodic_length", "td_loss", "q_mean")
] + [
    "team/return",
    "team/treasures_collected",
    "team/trap_rate",
    "eval/team_return",
    "eval/success_rate",
    "train/epsilon",
    "train/sps",
]


def learner_overrides(name: str) -> tuple[str, ...]:
    overrides, total, every = LEARNER_RUNS[name]
    return (*BASE, *overrides, f"total_steps={total}", f"eval_every={every}", "checkpoint_every=100")


def agent_tensors(path: Path) -> dict[str, np.ndarray]:
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        return {name: f.get_tensor(name) for name in f.keys()}  # noqa: SIM118 (safe_open has no __iter__)


def checkpoint_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "dqn_transfer.cli.ckpt", *args],
        cwd=REPO,
        env=train_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )


def file_bytes(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def launch_dir(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("launch")
    (path / "map.txt").write_text(MAP)
    return path


@pytest.fixture(scope="module")
def runs(launch_dir) -> dict:
    """Every successful short run of this module, started side by side."""
    jobs = {name: (*learner_overrides(name), "seed=0") for name in LEARNER_RUNS}
    jobs["dqn_again"] = jobs["dqn"]  # the same seed: must give the same results
    jobs["dqn_seed1"] = (*learner_overrides("dqn"), "seed=1")
    jobs["zero"] = (*BASE, "agent=dqn", "total_steps=0")
    names = list(jobs)
    results = run_many([(launch_dir, jobs[name], launch_dir / name) for name in names])
    return dict(zip(names, results))


# ---------------------------------------------------------------- 1. every learner runs from the CLI


@pytest.mark.parametrize("learner", list(LEARNER_RUNS))
def test_each_learner_runs_and_writes_the_run_directory(runs, learner):
    run = runs[learner]
    overrides, total, every = LEARNER_RUNS[learner]
    d = run.run_dir
    for i in range(NUM_AGENTS):
        assert (d / "checkpoints" / f"agent_{i}.safetensors").is_file()
    assert not (d / "checkpoints" / f"agent_{NUM_AGENTS}.safetensors").exists()
    assert (d / ".hydra" / "config.yaml").is_file()
    config = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
    assert config["agent"]["algorithm"] == learner
    assert config["env"]["mode"] == overrides[1].split("=")[1]
    assert config["total_steps"] == total
    assert "done" in (d / "train.log").read_text()
    assert list((d / "tb").glob("events.out.tfevents.*"))

    metrics = read_metrics(d)
    expected_steps = list(range(0, total + 1, every))
    if expected_steps[-1] != total:
        expected_steps.append(total)  # the end of training is always evaluated
    assert [m["step"] for m in metrics] == expected_steps
    for m in metrics:
        assert {"step", "team_return", "success_rate"} <= set(m)
        assert 0.0 <= m["success_rate"] <= 1.0
        # each agent takes at most one chest (+100); its worst episode is 24 steps (-1) then a trap (-100)
        assert NUM_AGENTS * (-(SIZE * SIZE - 1) - 100) <= m["team_return"] <= 100 * NUM_TREASURES


# ------------------------------------------------------------------------------ 2. TensorBoard


@pytest.fixture(scope="module")
def tensorboard_events(runs):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(runs["dqn"].run_dir / "tb"), size_guidance={"scalars": 0, "tensors": 0})
    acc.Reload()
    return acc


def test_tensorboard_has_every_documented_tag(tensorboard_events):
    scalars = set(tensorboard_events.Tags()["scalars"])
    missing = [tag for tag in TB_TAGS if tag not in scalars]
    assert not missing, f"missing TensorBoard tags {missing}; present: {sorted(scalars)}"
    eval_steps = [e.step for e in tensorboard_events.Scalars("eval/team_return")]
    assert eval_steps == [0, 100, 200, 300, 400]
    for tag in ("agent_0/td_loss", "agent_1/q_mean", "train/epsilon"):
        values = [e.value for e in tensorboard_events.Scalars(tag)]
        assert values and all(np.isfinite(values))
    epsilons = [e.value for e in tensorboard_events.Scalars("train/epsilon")]
    assert all(0.05 - 1e-6 <= v <= 1.0 for v in epsilons)
    assert epsilons == sorted(epsilons, reverse=True)  # linear decay


def test_tensorboard_custom_scalars_overlay_the_agents(tensorboard_events):
    from tensorboard.plugins.custom_scalar import layout_pb2

    tags = tensorboard_events.PluginTagToContent("custom_scalars")
    assert tags, "no custom-scalars layout"
    (tag,) = tags
    tensor = tensorboard_events.Tensors(tag)[0].tensor_proto
    layout = layout_pb2.Layout()
    layout.ParseFromString(tensor.string_val[0])
    charts = [set(chart.multiline.tag) for category in layout.category for chart in category.chart]
    for name in ("episodic_return", "td_loss"):
        assert {f"agent_{i}/{name}" for i in range(NUM_AGENTS)} in charts, charts


def test_tensorboard_has_config_text_and_hparams(tensorboard_events):
    text_tags = list(tensorboard_events.PluginTagToContent("text"))
    config_tags = [t for t in text_tags if t.startswith("config")]
    assert config_tags, text_tags
    text = tensorboard_events.Tensors(config_tags[0])[0].tensor_proto.string_val[0].decode()
    assert "agent.algorithm: dqn" in text and "env.mode: deliberative" in text
    assert tensorboard_events.PluginTagToContent("hparams")


# ------------------------------------------------------------------------------ 3. checkpoints


def test_checkpoints_are_self_describing_safetensors(runs):
    d = runs["dqn"].run_dir
    last = read_metrics(d)[-1]
    for i in range(NUM_AGENTS):
        path = d / "checkpoints" / f"agent_{i}.safetensors"
        meta = agent_meta(path)
        for key in (
            "algorithm",
            "obs_layout",
            "num_actions",
            "network",
            "env",
            "steps",
            "episodes",
            "last_eval",
            "digest",
        ):
            assert key in meta, key
        assert meta["algorithm"] == "dqn"
        # deliberative mode: position one-hot (n*n), what it knows of each chest, its assignment
        assert [list(s) for s in meta["obs_layout"]] == [
            ["position", SIZE * SIZE],
            ["treasures", NUM_TREASURES],
            ["assignment", NUM_TREASURES],
        ]
        assert meta["num_actions"] == 4
        assert meta["env"]["mode"] == "deliberative"
        assert meta["env"]["size"] == SIZE
        assert meta["steps"] == 400
        assert meta["episodes"] == last["episodes"]
        assert meta["last_eval"]["team_return"] == last["team_return"]
        assert meta["last_eval"]["success_rate"] == last["success_rate"]
        tensors = agent_tensors(path)
        obs_dim = SIZE * SIZE + 2 * NUM_TREASURES
        weights = [t for name, t in tensors.items() if t.ndim == 2]
        assert any(w.shape in ((32, obs_dim), (obs_dim, 32)) for w in weights), {n: t.shape for n, t in tensors.items()}
        assert all(np.isfinite(t).all() for t in tensors.values())


def test_checkpoint_cli_verifies_and_lists_a_run(runs):
    d = runs["dqn"].run_dir
    verify = checkpoint_cli("verify", str(d))
    assert verify.returncode == 0, verify.stderr
    listing = checkpoint_cli("list", str(d))
    assert listing.returncode == 0, listing.stderr
    rows = listing.stdout.strip().splitlines()
    assert len(rows) == NUM_AGENTS
    for i, row in enumerate(rows):
        assert f"agent_{i}.safetensors" in row and "dqn" in row and "steps=400" in row


def test_tabular_checkpoint_also_verifies(runs):
    meta = agent_meta(runs["sarsa"].run_dir / "checkpoints" / "agent_0.safetensors")
    assert meta["algorithm"] == "sarsa" and meta["steps"] == 300
    assert checkpoint_cli("verify", str(runs["sarsa"].run_dir)).returncode == 0


# -------------------------------------------------------------------------- 4. total_steps=0


def test_total_steps_zero_writes_initial_checkpoints_only(runs):
    d = runs["zero"].run_dir
    for i in range(NUM_AGENTS):
        meta = agent_meta(d / "checkpoints" / f"agent_{i}.safetensors")
        assert meta["steps"] == 0 and meta["episodes"] == 0
    assert [m for m in read_metrics(d) if m["step"] > 0] == []


# --------------------------------------------------------------------------- 5. reproducibility


def test_same_seed_same_results_different_seed_differs(runs):
    a, b, c = (read_metrics(runs[name].run_dir) for name in ("dqn", "dqn_again", "dqn_seed1"))
    assert without_timing(a) == without_timing(b)
    assert without_timing(a) != without_timing(c)
    digests = {
        name: [
            agent_meta(runs[name].run_dir / "checkpoints" / f"agent_{i}.safetensors")["digest"]
            for i in range(NUM_AGENTS)
        ]
        for name in ("dqn", "dqn_again", "dqn_seed1")
    }
    assert digests["dqn"] == digests["dqn_again"]  # bit-identical weights
    assert digests["dqn"] != digests["dqn_seed1"]


# ------------------------------------------------------------------------ 6. resume after SIGKILL

RESUME_RUN = (
    *BASE,
    "agent=dqn",
    "mode=cooperative",
    "agent.learning_starts=100",
    *SMALL_NET,
    "total_steps=1500",
    "checkpoint_every=500",
    "eval_every=125",
    "seed=3",
)


def _state_step(path: Path) -> int:
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        return json.loads(f.metadata()["meta"])["counters"]["step"]


def _complete_metric_steps(run_dir: Path) -> list[int]:
    return [record["step"] for record in read_metrics(run_dir)]


def _kill_after_an_uncheckpointed_eval(proc: subprocess.Popen, run_dir: Path, timeout: float = 240) -> int:
    """Wait for the first checkpoint and an evaluation after it, then SIGKILL; returns its step."""
    state = run_dir / "checkpoints" / "training_state.safetensors"
    deadline = time.monotonic() + timeout
    checkpointed = -1
    while time.monotonic() < deadline and proc.poll() is None:
        if state.exists():
            checkpointed = _state_step(state)
            steps = _complete_metric_steps(run_dir)
            if steps and steps[-1] > checkpointed:
                break
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    return checkpointed


@pytest.fixture(scope="module")
def resumed(launch_dir):
    """An uninterrupted run and the same run killed with SIGKILL and resumed, side by side."""
    reference = start_train(launch_dir, *RESUME_RUN, run_dir=launch_dir / "uninterrupted")
    killed_dir = launch_dir / "killed"
    proc = start_train(launch_dir, *RESUME_RUN, run_dir=killed_dir)
    checkpointed = _kill_after_an_uncheckpointed_eval(proc, killed_dir)
    killed_code = proc.returncode
    metrics_at_kill = _complete_metric_steps(killed_dir)
    result = run_train(launch_dir, *RESUME_RUN, "resume=true", run_dir=killed_dir, check=False)
    reference.wait(timeout=300)
    return {
        "killed_code": killed_code,
        "checkpointed": checkpointed,
        "metrics_at_kill": metrics_at_kill,
        "result": result,
        "reference_code": reference.returncode,
        "reference_dir": launch_dir / "uninterrupted",
    }


def test_sigkilled_run_resumes_to_the_end(resumed):
    assert resumed["killed_code"] == -signal.SIGKILL, "the run finished before it could be killed"
    assert 0 < resumed["checkpointed"] < 1500
    result = resumed["result"].check()
    d = result.run_dir
    for i in range(NUM_AGENTS):
        assert agent_meta(d / "checkpoints" / f"agent_{i}.safetensors")["steps"] == 1500
    steps = [m["step"] for m in read_metrics(d)]
    assert steps == sorted(set(steps)), steps  # strictly increasing: no duplicates
    assert steps[-1] == 1500
    assert steps == list(range(0, 1501, 125))
    assert checkpoint_cli("verify", str(d)).returncode == 0


def test_resumed_run_equals_the_uninterrupted_run(resumed):
    """Checkpoints carry the episode in progress and every RNG, so resuming changes nothing."""
    assert resumed["reference_code"] == 0
    assert resumed["killed_code"] == -signal.SIGKILL
    d, ref = resumed["result"].check().run_dir, resumed["reference_dir"]
    # the kill came after an evaluation the checkpoint did not cover: the resumed run redid it
    assert resumed["metrics_at_kill"][-1] > resumed["checkpointed"]
    assert without_timing(read_metrics(d)) == without_timing(read_metrics(ref))
    for i in range(NUM_AGENTS):
        a, b = (agent_meta(run / "checkpoints" / f"agent_{i}.safetensors") for run in (d, ref))
        assert a["digest"] == b["digest"]
        assert a["episodes"] == b["episodes"]


def test_resumed_tensorboard_has_no_duplicate_points(resumed):
    """Evaluations and episodes alike: the episodes' points wait in memory between log intervals, so
    the kill lost those after the last write; the resumed run logs again what its checkpoint did not
    cover, and its curves are the uninterrupted run's, with no gap and nothing twice."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    def points(run_dir: Path, tag: str) -> list[tuple[int, float]]:
        acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
        acc.Reload()
        return [(e.step, e.value) for e in acc.Scalars(tag)]

    resumed_dir = resumed["result"].run_dir
    assert [step for step, _ in points(resumed_dir, "eval/team_return")] == list(range(0, 1501, 125))
    for tag in ("team/return", "agent_1/episodic_length", "team/treasures_collected"):
        episodes = points(resumed_dir, tag)
        assert any(step > resumed["checkpointed"] for step, _ in episodes), tag
        assert episodes == points(resumed["reference_dir"], tag), tag


def test_resuming_a_finished_run_adds_no_evaluation(runs, tmp_path):
    """A requeued job that resumes an already finished run must not duplicate the last evaluation."""
    source = runs["qlearning"].run_dir  # total_steps=250, eval_every=100: the last eval is off the grid
    copy = tmp_path / "finished"
    shutil.copytree(source, copy)
    before = read_metrics(copy)
    run_train(source.parent, *learner_overrides("qlearning"), "resume=true", run_dir=copy)
    after = read_metrics(copy)
    assert [m["step"] for m in after] == [m["step"] for m in before] == [0, 100, 200, 250]


# ----------------------------------------------------------------------------- 7. bad input

# name -> (overrides, words the message must contain)
BAD_INPUTS = {
    "gamma_out_of_range": (("agent.gamma=1.5",), ("agent.gamma", "1.5")),
    "misspelt_key": (("agent.learning_rate=0.1",), ("learning_rate",)),
    "unknown_agent": (("agent=ppo",), ("agent=ppo", "no such option")),
    "missing_layout_file": (("env.layout_file=/nonexistent.txt",), ("/nonexistent.txt",)),
    "trap_beside_treasure": (("env.layout_file=trap_map.txt",), ("trap", "beside", "treasure")),
    "resume_empty_dir": (("resume=true",), ("resume",)),
    "infeasible_map": (("env.size=4", "env.complexity=0.99"), ("complexity",)),
    # refused when the config is checked, before the 20,000-step pretraining of the source
    "table_carrying_adam": (("agent=sarsa", "transfer=on", "transfer.reset_optimizer=false"), ("tabular",)),
    "partial_adam_carry": (
        ("transfer=on", "transfer.reset_optimizer=false", "transfer.targets=[1]"),
        ("every agent as a target",),
    ),
}
TRAP_MAP = "0.TX\n....\n....\n1..T\n"  # the trap at row 0, col 3 touches the chest at row 0, col 2


@pytest.fixture(scope="module")
def bad_runs(tmp_path_factory) -> dict:
    cwd = tmp_path_factory.mktemp("bad")
    (cwd / "trap_map.txt").write_text(TRAP_MAP)
    (cwd / "resume_empty_dir").mkdir()  # resume=true on an existing, empty directory
    names = list(BAD_INPUTS)
    jobs = [(cwd, (*BAD_INPUTS[name][0], "total_steps=50", "eval_every=25"), cwd / name) for name in names]
    return dict(zip(names, run_many(jobs, check=False)))


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_ends_in_one_clear_message(bad_runs, case):
    result = bad_runs[case]
    words = BAD_INPUTS[case][1]
    assert result.returncode != 0
    assert "Traceback" not in result.output, result.output
    for word in words:
        assert word in result.output, f"{word!r} not in the message:\n{result.output}"
    assert not (result.run_dir / "checkpoints").exists()
    assert not (result.run_dir / "metrics.jsonl").exists()
    assert not (result.run_dir / "tb").exists()
    ours = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(ours) <= 1, ours  # our own errors are one line; Hydra's own keep Hydra's format


def test_messages_name_the_problem_precisely(bad_runs):
    assert "error: agent.gamma must be in [0, 1], got 1.5" in bad_runs["gamma_out_of_range"].output
    assert "unknown config key 'agent.learning_rate'" in bad_runs["misspelt_key"].output
    assert "(did you mean agent.lr?)" in bad_runs["misspelt_key"].output
    assert "row 0, col 3" in bad_runs["trap_beside_treasure"].output
    assert "training_state" in bad_runs["resume_empty_dir"].output
    for case in ("table_carrying_adam", "partial_adam_carry"):
        assert "pretraining" not in bad_runs[case].output  # refused before the source's pretraining


# ------------------------------------------------------------------ 8. never overwrite a run


@pytest.fixture(scope="module")
def refused(runs, launch_dir):
    """A second, different run (seed=7) aimed at the finished total_steps=0 run's directory."""
    d = runs["zero"].run_dir
    before = file_bytes(d)
    result = run_train(launch_dir, *BASE, "agent=dqn", "total_steps=50", "seed=7", run_dir=d, check=False)
    return before, file_bytes(d), result


def _data_files(files: dict[str, bytes]) -> dict[str, bytes]:
    return {k: v for k, v in files.items() if not k.startswith((".hydra", "train.log"))}


def test_second_run_into_a_run_directory_is_refused(refused):
    before, after, result = refused
    assert result.returncode != 0
    assert "Traceback" not in result.output
    assert "already holds a run" in result.output and "resume=true" in result.output
    assert _data_files(after) == _data_files(before)  # checkpoints, metrics and TensorBoard untouched


def test_refused_run_keeps_the_runs_own_config_record(refused):
    before, after, _ = refused
    assert {k: v for k, v in after.items() if k.startswith(".hydra")} == {
        k: v for k, v in before.items() if k.startswith(".hydra")
    }


class _Killed(Exception):
    """Stands in for SIGKILL at an exact point of the loop."""


def kill_and_resume(tmp_path: Path, monkeypatch, config, dies, before: bool = False) -> tuple[list[dict], list[dict]]:
    """Run ``config(resume=False)`` uninterrupted into ``reference``; run it again into ``killed``,
    dying right after (``before``: right before) the first checkpoint where ``dies(trainer)``, then
    resume it from its last checkpoint.

    Returns the (resumed, reference) evaluations without their timing field.
    """
    from dqn_transfer.training.plan import plan_run
    from dqn_transfer.training.trainer import Trainer

    Trainer(plan_run(config()), tmp_path / "reference").run()
    original = Trainer.save_checkpoint

    def save_then_die(self):
        dying = self.step < self.config.total_steps and dies(self)
        if dying and before:
            raise _Killed
        original(self)
        if dying:
            raise _Killed

    monkeypatch.setattr(Trainer, "save_checkpoint", save_then_die)
    with pytest.raises(_Killed):
        Trainer(plan_run(config()), tmp_path / "killed").run()
    monkeypatch.setattr(Trainer, "save_checkpoint", original)
    Trainer(plan_run(config(resume=True)), tmp_path / "killed").run()
    return tuple(without_timing(read_metrics(tmp_path / name)) for name in ("killed", "reference"))


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
@pytest.mark.parametrize("before", [False, True], ids=["after_checkpoint", "between_evaluation_and_checkpoint"])
def test_a_kill_at_a_checkpoint_loses_nothing(tmp_path, monkeypatch, before):
    """In-process: die right after a checkpoint, or between the evaluation of its step and the
    checkpoint itself (metrics.jsonl then holds a line the previous checkpoint does not know).

    With ``eval_every=1`` every checkpoint step is also an evaluation step, and the checkpoints fall
    mid-episode. The resumed run must match an uninterrupted run, evaluation for evaluation.
    """
    from dqn_transfer.config import AgentConfig, TrainConfig
    from dqn_transfer.enums import Algorithm
    from dqn_transfer.envs.settings import EnvConfig

    def config(resume: bool = False) -> TrainConfig:
        return TrainConfig(
            env=EnvConfig(layout=MAP),
            agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.1),
            seed=2,
            total_steps=90,
            eval_every=1,
            eval_episodes=1,
            checkpoint_every=40,
            progress=False,
            resume=resume,
        )

    resumed, reference = kill_and_resume(
        tmp_path, monkeypatch, config, before=before, dies=lambda trainer: trainer.step > 40
    )
    assert [m["step"] for m in resumed] == list(range(91))
    assert resumed == reference


def test_resume_continues_with_the_runs_own_config(tmp_path):
    """`resume=true hydra.run.dir=DIR` alone continues a sarsa run as sarsa (the default agent is
    double_dqn), may extend total_steps, and refuses to change a learning setting."""
    from conftest import run_train

    first = run_train(tmp_path, "agent=sarsa", "agent.lr=0.3", "total_steps=300", "eval_every=100")
    refused = run_train(tmp_path, "resume=true", "agent.lr=0.5", check=False)
    assert refused.returncode != 0 and "Traceback" not in refused.output
    assert "'agent.lr=0.5' differs from the run's own setting (agent.lr=0.3)" in refused.stderr
    run_train(tmp_path, "resume=true", "total_steps=500")
    record = (first.run_dir / ".hydra" / "config.yaml").read_text()
    assert "algorithm: sarsa" in record and "lr: 0.3" in record and "total_steps: 500" in record
    steps = [json.loads(line)["step"] for line in (first.run_dir / "metrics.jsonl").read_text().splitlines()]
    assert steps == [0, 100, 200, 300, 400, 500]
    meta = agent_meta(first.run_dir / "checkpoints" / "agent_0.safetensors")
    assert meta["algorithm"] == "sarsa" and meta["steps"] == 500


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
@pytest.mark.parametrize("algorithm", ["dqn", "sarsa"])
@pytest.mark.parametrize("exchange", ["best", "shared_replay"])
def test_kill_mid_exchange_window_resumes_exactly(tmp_path, monkeypatch, exchange, algorithm):
    """The exchange window in progress (returns, pending shared transitions and their bounces) is checkpointed, so a run
    killed between two exchanges and resumed matches the uninterrupted run, networks and tables alike."""
    from dqn_transfer.config import AgentConfig, TrainConfig, TransferConfig
    from dqn_transfer.enums import Algorithm, Exchange
    from dqn_transfer.envs.settings import EnvConfig

    def config(resume: bool = False) -> TrainConfig:
        return TrainConfig(
            env=EnvConfig(layout=MAP),
            seed=0,
            total_steps=240,
            eval_every=40,
            eval_episodes=1,
            checkpoint_every=30,
            progress=False,
            resume=resume,
            agent=AgentConfig(algorithm=Algorithm(algorithm), hidden=[16], batch_size=8, learning_starts=30),
            transfer=TransferConfig(exchange=Exchange(exchange), exchange_every=5),
        )

    def mid_window(trainer) -> bool:  # shared_replay's window also holds an obstacle bounce, saved with it
        rep = trainer.replicas[0]
        return bool(rep.window_returns) and (exchange != "shared_replay" or bool(np.any(rep.exchange.bounced[0])))

    resumed, reference = kill_and_resume(tmp_path, monkeypatch, config, dies=mid_window)
    assert resumed == reference
    digests = [
        agent_meta(tmp_path / name / "checkpoints" / "agent_1.safetensors")["digest"]
        for name in ("killed", "reference")
    ]
    assert digests[0] == digests[1]  # bit-identical weights
