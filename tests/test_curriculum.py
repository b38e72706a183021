"""A curriculum of stages in one command: each stage warm-starts the next, stages are cached and
resumable, and the final run records its lineage. The shipped example (`curriculum=nested`) runs end
to end with short stages; an interrupted or killed curriculum, run again, gives exactly the result of
one that ran straight through."""

import dataclasses
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    agent_meta,
    assert_named_paths_exist,
    compose_config,
    read_metrics,
    run_train,
    start_train,
    without_timing,
)
from safetensors.numpy import load_file

import dqn_transfer.sources.curriculum
from dqn_transfer.config import (
    AgentConfig,
    ConfigError,
    CurriculumConfig,
    ReplicasConfig,
    StageConfig,
    TrainConfig,
    TransferConfig,
    validate,
)
from dqn_transfer.enums import Algorithm, Engine
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sources.curriculum import curriculum_sources
from dqn_transfer.training.plan import plan_run
from dqn_transfer.transfer.warm_start import lineage

# The shipped example with short stages: 5x5 (300 steps) -> 8x8 (3000 steps) -> this run's 12x12.
NESTED = (
    "curriculum=nested",
    "curriculum.stages.0.steps=300",
    "curriculum.stages.1.steps=3000",
    "total_steps=1500",
    "eval_every=500",
    "checkpoint_every=100",
    "agent.engine=numpy",
    "agent.learning_starts=50",
)


@pytest.mark.parametrize("option", ["nested", "grow"])
def test_the_shipped_curricula_compose(option):
    config = compose_config(f"curriculum={option}")
    validate(config)
    assert len(config.curriculum.stages) == 2 and config.transfer.enabled
    assert config.curriculum.stages[0].steps < config.curriculum.stages[1].steps < config.total_steps


@pytest.mark.parametrize(
    "overrides, message",
    [
        (("curriculum=grow", "transfer.enabled=false"), "needs transfer=on"),
        (("curriculum=grow", "transfer.source=somewhere"), "not from transfer.source=somewhere"),
        (
            ("curriculum=grow", "+curriculum.stages.0.env.sise=5"),
            r"curriculum.stages\[0\].env: unknown env key\(s\) \['sise'\]",
        ),
        (("curriculum=grow", "curriculum.stages.1.steps=0"), r"curriculum.stages\[1\].steps must be >= 1"),
        (("curriculum=grow", "curriculum.stages.1.offset=[1]"), r"curriculum.stages\[1\].offset must be \[row, col\]"),
    ],
)
def test_a_bad_curriculum_is_refused_naming_the_stage(overrides, message):
    with pytest.raises(ConfigError, match=message):
        validate(compose_config(*overrides))


# ------------------------------------------------------------------------------ caching, in-process

SMALL, LARGE = "0.T\n...\n..X", "0....\n...T.\n.....\n...X.\n1...."  # SMALL sits at (1, 1) in LARGE


def lone_config(cache: Path, first_steps: int = 30, *, replicas: int = 1) -> TrainConfig:
    stages = [
        StageConfig(env={"layout": SMALL}, steps=first_steps),
        StageConfig(env={"layout": LARGE.replace("1", ".")}, steps=40, offset=[1, 1]),
    ]
    return TrainConfig(
        env=EnvConfig(layout=LARGE, size=5, num_treasures=1, num_traps=1, num_agents=2, complexity=0.0),
        agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.5, engine=Engine.numpy),
        transfer=TransferConfig(enabled=True),
        curriculum=CurriculumConfig(stages=stages, cache_dir=str(cache)),
        replicas=ReplicasConfig(seeds=replicas),
        total_steps=0,
        eval_episodes=1,
        progress=False,
    )


@pytest.fixture
def counted_stages(monkeypatch):
    """The steps of every stage run the curriculum trains (reused stages train nothing)."""
    runs: list[int] = []
    real = dqn_transfer.sources.curriculum.train_on_cores

    def counted(plan, *args, **kwargs):
        runs.append(plan.config.total_steps)
        return real(plan, *args, **kwargs)

    monkeypatch.setattr(dqn_transfer.sources.curriculum, "train_on_cores", counted)
    return runs


def test_stages_are_cached_and_a_changed_stage_retrains_what_follows(tmp_path, counted_stages):
    cache = tmp_path / "cache"
    first = curriculum_sources(plan_run(lone_config(cache)), tmp_path)
    assert counted_stages == [30, 40]
    assert [p.name for p in first[0]] == ["agent_0.safetensors"] * 2  # both agents from stage 2's agent 0
    assert curriculum_sources(plan_run(lone_config(cache)), tmp_path) == first and counted_stages == [30, 40]  # reused
    changed = lone_config(cache)
    changed.curriculum.stages[1].steps = 50
    curriculum_sources(plan_run(changed), tmp_path)
    assert counted_stages == [30, 40, 50]  # the first stage is reused, the changed one retrained
    curriculum_sources(plan_run(lone_config(cache, first_steps=31)), tmp_path)
    assert counted_stages == [30, 40, 50, 31, 40]  # a changed first stage retrains the second too
    assert len([p for p in cache.iterdir() if not p.name.startswith(".")]) == 5  # 2 + the changed 1 + 2
    assert not [p for p in cache.iterdir() if ".partial" in p.name or ".tmp" in p.name]
    spread = lone_config(cache)
    spread.replicas.workers = "2"  # how the replicas are spread over processes: not part of a stage
    curriculum_sources(plan_run(spread), tmp_path)
    assert counted_stages == [30, 40, 50, 31, 40]  # reused


def test_each_stage_starts_from_the_previous_one(tmp_path):
    sources = curriculum_sources(plan_run(lone_config(tmp_path / "cache")), tmp_path)
    second = agent_meta(sources[0][0])
    assert second["steps"] == 40 and second["env"]["size"] == 5
    assert second["transfer"]["mapping"] == {"source_size": 3, "offset": [1, 1], "fill": "zero", "dropped_chests": []}
    first = Path(second["transfer"]["source"])
    assert agent_meta(first)["steps"] == 30 and agent_meta(first)["transfer"] is None
    assert second["transfer"]["source_transfer"] is None  # the first stage trained from scratch


def test_replicas_have_a_chain_of_stages_each_trained_as_one_batch(tmp_path, counted_stages):
    sources = curriculum_sources(plan_run(lone_config(tmp_path / "cache", replicas=2)), tmp_path)
    assert counted_stages == [30, 40]  # each stage once, for both replicas
    assert len(sources) == 2 and sources[0] != sources[1]
    lone = curriculum_sources(plan_run(dataclasses.replace(lone_config(tmp_path / "lone"), seed=1)), tmp_path)
    assert agent_meta(sources[1][0])["digest"] == agent_meta(lone[0][0])["digest"]  # replica = lone run of its seed


# ------------------------------------------------------------------------------- the command line


def final_run(run_dir: Path) -> tuple[list[dict], list[str], dict[str, np.ndarray]]:
    """What a curriculum's result is: its evaluations, the digests of the stages it started from (the
    paths differ with the launch directory) and its agents' tensors."""
    records = without_timing(read_metrics(run_dir))
    chain = [step["digest"] for step in lineage(records[0].pop("transfer_source"))]
    tensors = {
        f"{i}/{name}": value
        for i in range(4)
        for name, value in load_file(run_dir / "checkpoints" / f"agent_{i}.safetensors").items()
    }
    return records, chain, tensors


@pytest.fixture(scope="module")
def straight_through(tmp_path_factory):
    """The shipped example, uninterrupted."""
    work = tmp_path_factory.mktemp("straight")
    return run_train(work, *NESTED), work


@pytest.mark.slow
def test_the_example_curriculum_runs_and_records_its_lineage(straight_through):
    result, work = straight_through
    assert result.output.count("curriculum: training stage") == 2
    start = read_metrics(result.run_dir)[0]["transfer_source"]
    assert start["mapping"]["source_size"] == 8 and start["mapping"]["offset"] == [2, 2]
    assert [entry["source_agent"] for entry in start["per_target"]] == [0, 1, 0, 1]
    assert start["source_transfer"]["mapping"]["source_size"] == 5  # the chain back to the first stage
    meta = agent_meta(result.run_dir / "checkpoints" / "agent_3.safetensors")
    assert meta["transfer"]["source_transfer"]["source_steps"] == 300 and meta["transfer"]["source_steps"] == 3000

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(result.run_dir / "tb"), size_guidance={"tensors": 0})
    events.Reload()
    table = events.Tensors("transfer/lineage")[0].tensor_proto.string_val[0].decode()
    rows = table.splitlines()[2:]
    assert [row.split(" | ")[2:5] for row in rows] == [["5x5", "300", "[1, 1]"], ["8x8", "3000", "[2, 2]"]]


def wait_for(root: Path, pattern: str, proc, timeout: float = 120.0) -> Path:
    """The first path under ``root`` matching ``pattern`` once it exists, while ``proc`` runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = sorted(root.glob(pattern)) if root.exists() else []
        if found:
            return found[0]
        assert proc.poll() is None, f"the run ended before {pattern} appeared"
        time.sleep(0.01)
    raise AssertionError(f"no {pattern} under {root} after {timeout} s")


@pytest.mark.slow
def test_a_curriculum_killed_between_stages_or_stopped_in_one_resumes_to_the_same_result(tmp_path, straight_through):
    reference, reference_work = straight_through
    run_dir = tmp_path / "run"
    cache = tmp_path / "outputs" / "curriculum"

    # SIGKILL once the first stage is cached: nothing of the process gets to clean up.
    proc = start_train(tmp_path, *NESTED, run_dir=run_dir)
    wait_for(cache, "[0-9a-f]*", proc)
    proc.kill()
    proc.wait()
    # Ctrl-C inside the second stage, once this process has written a checkpoint there: the stage keeps it.
    proc = start_train(tmp_path, *NESTED, run_dir=tmp_path / "run_again")
    wait_for(tmp_path, "run_again.out", proc)
    while "stage 2 of 3 (" not in (tmp_path / "run_again.out").read_text():
        assert proc.poll() is None
        time.sleep(0.01)
    state = wait_for(cache, ".*.partial/checkpoints/training_state.safetensors", proc)
    written = state.stat().st_mtime_ns
    while not state.exists() or state.stat().st_mtime_ns == written:  # a checkpoint of this process
        assert proc.poll() is None, "stage 2 ended before it wrote a checkpoint"
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 130
    out = (tmp_path / "run_again.out").read_text()
    assert "interrupted in a curriculum stage, kept at its last checkpoint" in out
    assert not (tmp_path / "run_again" / "metrics.jsonl").exists()  # the run itself never started

    result = run_train(tmp_path, *NESTED, run_dir=tmp_path / "run_last")
    assert "reused from" in result.output and "curriculum: resuming stage 2 of 3" in result.output
    (records, chain, ours), (expected, expected_chain, theirs) = final_run(result.run_dir), final_run(reference.run_dir)
    assert records == expected and chain == expected_chain and len(chain) == 2
    assert ours.keys() == theirs.keys() and all(np.array_equal(ours[k], theirs[k]) for k in ours)
    stages = sorted(p.name for p in cache.iterdir() if not p.name.startswith("."))
    assert stages == sorted(
        p.name for p in (reference_work / "outputs" / "curriculum").iterdir() if not p.name.startswith(".")
    )
    assert not [p for p in cache.iterdir() if ".partial" in p.name or ".tmp" in p.name]


@pytest.mark.slow
def test_a_curriculums_lines_name_existing_paths_and_tag_its_stages(straight_through):
    """Stages were logged in their ``.partial`` work directories, renamed away after; and a stage's
    evaluations looked like the run's own."""
    result, work = straight_through
    named = assert_named_paths_exist(result.output, work)
    assert not [p for p in named if ".partial" in str(p) or ".tmp" in str(p)]
    lines = result.output.splitlines()
    for n in (1, 2):
        tagged = [line for line in lines if f"[curriculum stage {n}/3]" in line]
        assert any("eval step 0:" in line for line in tagged) and any("done:" in line for line in tagged)
    own = [line for line in lines if "eval step" in line and "[curriculum stage" not in line]
    assert len(own) == 4  # the run's own: steps 0, 500, 1000, 1500
