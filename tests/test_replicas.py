"""Replicas: N seeds x M maps as independent runs in one process, each a complete run directory.

The reference for every replica is the lone run of its own seed and map seed, trained separately.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import agent_meta, read_metrics, run_train, without_timing
from safetensors.numpy import load_file

from dqn_transfer.agents import DQNLearner, Transition
from dqn_transfer.analysis.runs import find_run_dirs, load_config
from dqn_transfer.config import AgentConfig, ConfigError, ReplicasConfig, TrainConfig, TransferConfig, validate
from dqn_transfer.enums import Algorithm, Mode
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sources.resolve import resolve_source
from dqn_transfer.storage.checkpoint import CheckpointError, find_checkpoints
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

ENV = EnvConfig(size=5, num_treasures=2, complexity=0.1, map_seed=3, mode=Mode.cooperative)
DQN = AgentConfig(
    algorithm=Algorithm.double_dqn,
    hidden=[16],
    batch_size=8,
    learning_starts=40,
    buffer_size=500,
    target_update=30,
    train_freq=2,
)
SARSA = AgentConfig(algorithm=Algorithm.sarsa, lr=0.1)


def config(
    agent: AgentConfig = DQN, seeds: int = 1, maps: int = 1, seed: int = 4, map_seed: int = 3, **top
) -> TrainConfig:
    return TrainConfig(
        env=dataclasses.replace(ENV, map_seed=map_seed),
        agent=agent,
        seed=seed,
        replicas=ReplicasConfig(seeds=seeds, maps=maps),
        **{**dict(total_steps=240, eval_every=80, eval_episodes=2, checkpoint_every=100, progress=False), **top},
    )


def run_files(run_dir: Path) -> dict[str, object]:
    """What two runs that are the same must share: evaluations, agent tensors, resume arrays."""
    files: dict[str, object] = {"metrics": without_timing(read_metrics(run_dir))}
    for path in sorted((run_dir / "checkpoints").glob("*.safetensors")):
        files.update({f"{path.name}:{name}": array for name, array in load_file(str(path)).items()})
    return files


def assert_same_run(a: Path, b: Path) -> None:
    files_a, files_b = run_files(a), run_files(b)
    assert files_a.keys() == files_b.keys()
    for name, value in files_a.items():
        if isinstance(value, np.ndarray):
            assert np.array_equal(value, files_b[name]), name
        else:
            assert value == files_b[name], name


@pytest.mark.parametrize(
    "agent",
    [dataclasses.replace(DQN, learning_starts=10_000), DQN, SARSA],
    ids=["dqn_nothing_learned", "dqn_learning", "sarsa"],
)
def test_each_replica_is_the_lone_run_of_its_seed_and_map(tmp_path, agent):
    """3 seeds x 2 maps (six games in one batch): every replica's evaluations, agent files and resume
    state are those of the lone run with its seed and map seed. Bit for bit, learning included: on the
    CPU each member's batched matrix product is computed on its own, so a replica's numbers do not
    depend on its neighbours."""
    Trainer(plan_run(config(agent, seeds=3, maps=2)), tmp_path / "batch").run()
    names = sorted(p.name for p in (tmp_path / "batch").iterdir() if p.is_dir() and not p.name.startswith("."))
    assert names == [f"seed_{s}-map_{m}" for s in (4, 5, 6) for m in (3, 4)]
    for seed, map_seed in ((4, 3), (6, 4)):  # the first replica and the last one
        Trainer(plan_run(config(agent, seed=seed, map_seed=map_seed)), tmp_path / f"lone_{seed}_{map_seed}").run()
        assert_same_run(tmp_path / "batch" / f"seed_{seed}-map_{map_seed}", tmp_path / f"lone_{seed}_{map_seed}")


def test_changing_one_replicas_data_leaves_the_others_updates_bit_identical():
    """Two batches of two replicas; replica 0 sees different data in each, replica 1 the same. Replica
    1's weights, targets and Adam moments come out identical, and differ from replica 0's."""
    rng = np.random.default_rng(0)
    d, k, steps = 6, 2, 60
    same_half = [rng.random((k, d), dtype=np.float32) for _ in range(steps)]
    learners = [
        DQNLearner(k, [("position", d)], 3, dataclasses.replace(DQN, learning_starts=4), seed=[1, 2]) for _ in range(2)
    ]
    for trial, learner in enumerate(learners):
        data = np.random.default_rng(100 + trial)  # replica 0's data differs between the two batches
        for step in range(1, steps + 1):
            obs = np.concatenate([data.random((k, d), dtype=np.float32), same_half[step - 1]])
            actions = learner.act(obs, np.ones(2 * k, bool), epsilon=0.5)
            rewards = np.concatenate([data.normal(size=k), np.linspace(-1, 1, k)]).astype(np.float32)
            learner.update(
                Transition(
                    obs, actions, rewards, 1.0 - obs, np.zeros(2 * k, bool), np.zeros(2 * k, bool), np.ones(2 * k, bool)
                ),
                step,
            )
    assert learners[0].num_gradient_steps > 20
    replica_1 = [learner.replica(1) for learner in learners]
    for i in range(k):
        a, b = (r.agent_tensors(i) for r in replica_1)
        assert all(np.array_equal(a[name], b[name]) for name in a), i
    states = [r.training_state()[0] for r in replica_1]
    assert all(np.array_equal(states[0][name], states[1][name]) for name in states[0])
    a, b = (learner.replica(0).agent_tensors(0) for learner in learners)
    assert not np.array_equal(a["q.layers.0.weight"], b["q.layers.0.weight"])


@pytest.mark.parametrize("agent", [DQN, SARSA], ids=["dqn", "sarsa_compiled_steps"])
def test_replicas_resume_exactly_from_a_mid_episode_checkpoint(tmp_path, monkeypatch, agent):
    """Killed right after its first checkpoint (step 100, in the middle of episodes) and resumed, a
    batch of replicas ends exactly where the uninterrupted batch does."""
    Trainer(plan_run(config(agent, seeds=2, maps=1)), tmp_path / "reference").run()
    original = Trainer.save_checkpoint

    def save_then_die(self):
        original(self)
        if self.step == 100:
            raise KeyboardInterrupt

    monkeypatch.setattr(Trainer, "save_checkpoint", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        Trainer(plan_run(config(agent, seeds=2)), tmp_path / "killed").run()
    monkeypatch.setattr(Trainer, "save_checkpoint", original)
    state = agent_meta(tmp_path / "killed" / "seed_4" / "checkpoints" / "training_state.safetensors")
    assert state["counters"]["step"] == 100 and state["episode"] is not None  # mid-episode
    Trainer(plan_run(config(agent, seeds=2, resume=True)), tmp_path / "killed").run()
    for name in ("seed_4", "seed_5"):
        assert_same_run(tmp_path / "killed" / name, tmp_path / "reference" / name)


def test_an_evaluation_depends_on_neither_eval_every_nor_the_replicas_beside_it(tmp_path):
    """The evaluation at step N plays episodes seeded from (seed, N, episode) alone (issue #31): 2
    replicas evaluated every 40 steps in one batch of the batched evaluation record at steps 0, 80, 160,
    240 what the lone run of each seed, evaluated every 80 steps, records there. SARSA's ties between
    equal values are drawn from the evaluation's generators, so other generators give other numbers."""
    Trainer(plan_run(config(SARSA, seeds=2, eval_every=40)), tmp_path / "batch").run()
    for seed in (4, 5):
        Trainer(plan_run(config(SARSA, seed=seed)), tmp_path / f"lone_{seed}").run()
        lone = without_timing(read_metrics(tmp_path / f"lone_{seed}"))
        replica = without_timing(read_metrics(tmp_path / "batch" / f"seed_{seed}"))
        assert [record["step"] for record in lone] == [0, 80, 160, 240]
        assert [record for record in replica if record["step"] % 80 == 0] == lone
        assert len({record["team_return"] for record in replica}) > 1  # the episodes' numbers vary: not vacuous


def test_a_replica_directory_reads_like_a_lone_run(tmp_path):
    """Its own config (seed, map seed, no replicas) where Hydra puts a run's; the analysis finds the
    replicas, not the batch directory; a replica serves as a transfer source and warm-starts every
    replica of a new batch."""
    batch = tmp_path / "batch"
    Trainer(plan_run(config(seeds=2, maps=2)), batch).run()
    replicas = find_run_dirs([batch])
    assert [p.name for p in replicas] == ["seed_4-map_3", "seed_5-map_3", "seed_4-map_4", "seed_5-map_4"]
    own = load_config(batch / "seed_5-map_4")
    assert (
        own["seed"] == 5
        and own["env"]["map_seed"] == 4
        and own["replicas"] == {"seeds": 1, "maps": 1, "workers": "auto"}
    )
    assert find_run_dirs([tmp_path]) == sorted(replicas, key=lambda p: p.name)

    files = find_checkpoints(batch)  # every replica's agent files, replica by replica
    assert [f"{f.parent.parent.name}/{f.name}" for f in files] == [
        f"{name}/agent_{i}.safetensors"
        for name in ("seed_4-map_3", "seed_5-map_3", "seed_4-map_4", "seed_5-map_4")
        for i in range(2)
    ]
    with pytest.raises(CheckpointError, match="is a run of 4 replicas: pass one replica's directory"):
        resolve_source(TransferConfig(enabled=True, source=str(batch)), tmp_path, 1)

    source = batch / "seed_4-map_3"
    warm = config(seeds=2, total_steps=0, transfer=TransferConfig(enabled=True, source=str(source)))
    trainer = Trainer(plan_run(warm), tmp_path / "warm", sources=[source / "checkpoints" / "agent_0.safetensors"] * 2)
    trainer.run()
    for rep in trainer.replicas:
        assert rep.transfer_info["targets"] == [0, 1]
        for i in range(2):
            got = rep.learner.agent_tensors(i)["q.layers.0.weight"]
            assert np.array_equal(
                got, load_file(str(source / "checkpoints" / "agent_0.safetensors"))["q.layers.0.weight"]
            )


def test_replicas_of_maps_need_a_generated_map():
    with pytest.raises(ConfigError, match=r"replicas.maps=2 needs a generated map"):
        validate(dataclasses.replace(config(maps=2), env=EnvConfig(layout="0.T\n...\n1.T")))
    validate(dataclasses.replace(config(seeds=3), env=EnvConfig(layout="0.T\n...\n1.T")))  # seeds are fine


@pytest.mark.slow
def test_the_command_line_runs_and_resumes_replicas_and_refuses_map_replicas_of_a_layout(tmp_path):
    result = run_train(tmp_path, "agent=sarsa", "replicas.seeds=2", "total_steps=200", "eval_every=100")
    for seed in (0, 1):
        replica = result.run_dir / f"seed_{seed}"
        assert [m["step"] for m in read_metrics(replica)] == [0, 100, 200]
        assert (replica / "checkpoints" / "training_state.safetensors").exists() and (replica / "tb").is_dir()
    run_train(tmp_path, "resume=true", "total_steps=300", run_dir=result.run_dir)  # the batch's own config
    for seed in (0, 1):
        replica = result.run_dir / f"seed_{seed}"
        assert [m["step"] for m in read_metrics(replica)] == [0, 100, 200, 300]
        assert load_config(replica)["agent"]["algorithm"] == "sarsa"
    refused = run_train(tmp_path, "replicas.maps=2", "env.layout=0.T", run_dir=tmp_path / "refused", check=False)
    assert refused.returncode == 1 and "Traceback" not in refused.output
    assert "replicas.maps=2 needs a generated map" in refused.stderr
    assert not (tmp_path / "refused").exists()
