"""``transfer=on`` end to end (docs/transfer.md): function preservation through the real Trainer path,
refusal of incompatible or unsafe sources on the command line, the pretrained-source cache, a seeded
jumpstart experiment, what a run records about its source, and targets / freeze / exchange.

Independence from the code under test: source checkpoints are read back with ``safetensors`` alone,
the reference Q-function is a plain ``nn.Sequential`` built from those tensors, and observations are
assembled from the rules of docs/game.md (``position`` one-hot of ``row * n + col`` first, then ``treasures``, then
``assignment``), not from the mapping code.

Cost: sources are trained once per module on 5 x 5 maps (tens to a few thousand steps); the CLI
refusals are the only subprocesses and run side by side (``conftest.run_many``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import reference_mlp, run_many
from safetensors import safe_open
from safetensors.numpy import load_file
from torch import nn

from dqn_transfer.analysis.compare import compare_runs
from dqn_transfer.analysis.runs import learning_curve
from dqn_transfer.analysis.transfer_metrics import jumpstart
from dqn_transfer.config import AgentConfig, ConfigError, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Engine, Exchange, Mode
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.sources.resolve import transfer_sources
from dqn_transfer.storage.checkpoint import CheckpointError
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer
from dqn_transfer.transfer.mapping import TransferError

N = 5  # map side of every map below
NUM_ACTIONS = 4

# Team map: two agents, two chests (row 0 col 4, row 4 col 4), one trap (row 2 col 2), no obstacles.
TEAM_MAP = "0...T\n.....\n..X..\n.....\n1...T\n"
# Jumpstart map: one agent, one chest four moves away (row 2 col 2), one trap in a corner.
SOLO_MAP = "0....\n.....\n..T..\n.....\n....X\n"

DQN_AGENT = dict(
    algorithm=Algorithm.dqn,
    engine=Engine.torch,  # the checks below run the target's torch network
    hidden=[32, 32],
    batch_size=32,
    buffer_size=5_000,
    learning_starts=50,
    target_update=100,
    tau=1.0,
)
QL_AGENT = dict(algorithm=Algorithm.qlearning, lr=0.5)


@pytest.fixture(scope="module", autouse=True)
def one_torch_thread():
    """Tiny networks: intra-op threads only add contention on a shared 2-core machine (10x slower)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def env_config(layout: str, mode: Mode = Mode.cooperative) -> EnvConfig:
    """The layout, with generation parameters that agree with it (no 'layout differs' warning)."""
    return EnvConfig(
        layout=layout,
        size=N,
        num_treasures=layout.count("T"),
        num_traps=layout.count("X"),
        num_agents=sum(ch.isdigit() for ch in layout),
        complexity=0.0,
        mode=mode,
    )


def make_config(
    layout: str,
    agent: dict,
    *,
    mode: Mode = Mode.cooperative,
    seed: int = 0,
    total_steps: int = 0,
    transfer: TransferConfig | None = None,
    **top,
) -> TrainConfig:
    top = {"eval_episodes": 1, "progress": False, **top}
    return TrainConfig(
        env=env_config(layout, mode),
        agent=AgentConfig(**agent),
        seed=seed,
        total_steps=total_steps,
        eval_every=max(1, total_steps),
        checkpoint_every=max(1, total_steps),
        transfer=transfer or TransferConfig(),
        **top,
    )


def make_trainer(config: TrainConfig, run_dir: Path, launch_dir: Path) -> Trainer:
    """What ``python train.py`` builds: the transfer source found (or pretrained) first, then the trainer."""
    return Trainer(plan_run(config), run_dir, sources=transfer_sources(plan_run(config), launch_dir))


def train_source(run_dir: Path, layout: str, agent: dict, total_steps: int, **top) -> Path:
    """Train on the source task (TreasureHunt-v0 of the map) and return agent 0's checkpoint."""
    config = make_config(layout, agent, total_steps=total_steps, **top)
    Trainer(plan_run(config, source_task=True), run_dir).run()
    return run_dir / "checkpoints" / "agent_0.safetensors"


def header_meta(path: Path) -> dict:
    with safe_open(str(path), framework="pt") as f:
        return json.loads(f.metadata()["meta"])


def source_mlp(path: Path) -> nn.Sequential:
    """The source's online Q-network as a plain nn.Sequential (nn.Linear layout ``[out, in]``)."""
    return reference_mlp(load_file(str(path)))


def random_observations(mode: Mode, num_treasures: int, count: int, rng: np.random.Generator):
    """``(position one-hot [count, n*n], expanded obs [count, D])`` in the observation's documented
    segment order (docs/game.md): observations the game can produce (an assignment is one chest or none)."""
    position = np.eye(N * N, dtype=np.float32)[rng.integers(N * N, size=count)]
    parts = [position, rng.integers(0, 2, size=(count, num_treasures)).astype(np.float32)]
    if mode is Mode.deliberative:
        parts.append(np.eye(num_treasures + 1, dtype=np.float32)[rng.integers(num_treasures + 1, size=count), 1:])
    return position, np.concatenate(parts, axis=1)


def expected_layout(mode: Mode, k: int) -> list[tuple[str, int]]:
    return [("position", N * N), ("treasures", k)] + ([("assignment", k)] if mode is Mode.deliberative else [])


# ------------------------------------------------------------------------------ module-wide sources


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("transfer")


@pytest.fixture(scope="module")
def dqn_source(work) -> Path:
    """A DQN agent trained briefly on the team map's source task (weights moved by ~250 updates)."""
    return train_source(work / "dqn_source", TEAM_MAP, DQN_AGENT, 300)


@pytest.fixture(scope="module")
def tabular_source(work) -> Path:
    return train_source(work / "ql_source", TEAM_MAP, QL_AGENT, 1_500)


# ----------------------------------------------------------------------------- function preservation


@pytest.mark.parametrize("mode", [Mode.cooperative, Mode.deliberative])
def test_dqn_transfer_preserves_the_source_q_function(work, dqn_source, mode):
    meta = header_meta(dqn_source)
    assert meta["obs_layout"] == [["position", N * N]] and meta["source_task"] and meta["steps"] == 300
    config = make_config(
        TEAM_MAP, DQN_AGENT, mode=mode, seed=1, transfer=TransferConfig(enabled=True, source=str(dqn_source))
    )
    trainer = make_trainer(config, work / f"fp_dqn_{mode.value}", work)
    assert trainer.replicas[0].game.obs_layout() == expected_layout(mode, 2)
    trainer.run()  # total_steps=0: transfer, write the initial checkpoints, stop

    position, obs = random_observations(mode, 2, 200, np.random.default_rng(0))
    with torch.no_grad():
        expected = source_mlp(dqn_source)(torch.from_numpy(position))
        batch = torch.from_numpy(np.stack([obs, obs]))  # [K=2, B, D]
        got = trainer.learner.q_network(batch)
    assert got.shape == (2, 200, NUM_ACTIONS)
    for agent in range(2):
        torch.testing.assert_close(got[agent], expected, rtol=1e-5, atol=1e-5)
    # Not vacuous: the source's Q-values depend on the position, and a random net would differ.
    assert expected.std(dim=0).min() > 1e-3
    fresh = Trainer(plan_run(dataclasses.replace(config, transfer=TransferConfig())), work / f"fp_fresh_{mode.value}")
    with torch.no_grad():
        assert not torch.allclose(fresh.learner.q_network(batch)[0], expected, atol=1e-2)


@pytest.mark.parametrize("mode", [Mode.cooperative, Mode.deliberative])
def test_tabular_transfer_preserves_the_source_table(work, tabular_source, mode):
    source = load_file(str(tabular_source))
    keys, values = source["keys"], source["values"]
    visited = keys.argmax(axis=1)
    assert keys.shape[1] == N * N and len(visited) >= 10 and np.abs(values).max() > 1.0
    config = make_config(
        TEAM_MAP, QL_AGENT, mode=mode, transfer=TransferConfig(enabled=True, source=str(tabular_source))
    )
    trainer = make_trainer(config, work / f"fp_ql_{mode.value}", work)
    trainer.run()

    rng = np.random.default_rng(1)
    for row, cell in enumerate(visited):
        for _ in range(3):  # expanded observations the target has never seen, random s_env bits
            _, obs = random_observations(mode, 2, 1, rng)
            obs[0, : N * N] = np.eye(N * N, dtype=np.float32)[cell]
            for agent in range(2):
                np.testing.assert_array_equal(trainer.learner.agent_q_values(agent, obs[0]), values[row])
    unvisited = sorted(set(range(N * N)) - set(visited.tolist()))
    if unvisited:  # a cell the source never saw is worth 0, as for a fresh table
        _, obs = random_observations(mode, 2, 1, rng)
        obs[0, : N * N] = np.eye(N * N, dtype=np.float32)[unvisited[0]]
        assert not trainer.learner.agent_q_values(0, obs[0]).any()


# --------------------------------------------------------------------------- CLI refusal of sources


class _Plant:
    """Unpickling this creates ``marker``: what a malicious shared 'checkpoint' could do."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


TEAM_CLI = (
    "agent=dqn",
    "agent.hidden=[32,32]",
    "mode=cooperative",
    "env.layout_file=team_map.txt",
    f"env.size={N}",
    "env.num_treasures=2",
    "env.num_traps=1",
    "env.num_agents=2",
    "env.complexity=0.0",
    "env.map_seed=0",
    "transfer=on",
    "total_steps=0",
)  # generation keys agree with the layout: no warning


@pytest.fixture(scope="module")
def cli_refusals(work, dqn_source, tabular_source):
    """Every bad source on the command line, run side by side; {case: (TrainResult, expected words)}."""
    cwd = work / "cli"
    bad = cwd / "bad"
    bad.mkdir(parents=True)
    (cwd / "team_map.txt").write_text(TEAM_MAP)

    marker = cwd / "PWNED"
    planted = pickle.dumps(_Plant(str(marker)))
    (bad / "disguised").mkdir()
    (bad / "disguised" / "agent_0.safetensors").write_bytes(planted)
    torch.save({"q.layers.0.weight": torch.zeros(32, 27)}, bad / "model.pt")
    data = dqn_source.read_bytes()
    (bad / "truncated.safetensors").write_bytes(data[: len(data) // 2])
    flipped = bytearray(data)
    flipped[-5] ^= 0x10  # inside the last tensor's bytes: still a valid file, wrong digest
    (bad / "flipped.safetensors").write_bytes(bytes(flipped))
    other_hidden = train_source(work / "hidden16_source", TEAM_MAP, {**DQN_AGENT, "hidden": [16]}, 0)

    cases = {
        "pickle_disguised": (bad / "disguised" / "agent_0.safetensors", TEAM_CLI, ("pickle", "refusing")),
        "torch_save_pt": (bad / "model.pt", TEAM_CLI, ("pickle", "refusing")),
        "truncated": (bad / "truncated.safetensors", TEAM_CLI, ("truncated",)),
        "bit_flipped": (bad / "flipped.safetensors", TEAM_CLI, ("digest mismatch",)),
        "missing": (bad / "nowhere.safetensors", TEAM_CLI, ("no such file",)),
        # a generated 4 x 4 map: smaller than the source's 5 x 5 (a larger one would take it, at transfer.offset)
        "larger_source_map": (
            dqn_source,
            ("agent=dqn", "agent.hidden=[32,32]", "transfer=on", "total_steps=0", "env.size=4"),
            ("5x5 map does not fit in this run's 4x4 map",),
        ),
        "tabular_for_dqn": (tabular_source, TEAM_CLI, ("tabular", "dqn")),
        "other_hidden": (other_hidden, TEAM_CLI, ("hidden layers differ", "[16]", "[32, 32]")),
    }
    jobs = [
        (cwd, (*overrides, f"transfer.source={path}"), cwd / f"run_{name}")
        for name, (path, overrides, _) in cases.items()
    ]
    results = run_many(jobs, check=False)
    return {name: (result, words) for (name, (_, _, words)), result in zip(cases.items(), results)}, marker, planted


@pytest.mark.slow
@pytest.mark.parametrize(
    "case",
    [
        "pickle_disguised",
        "torch_save_pt",
        "truncated",
        "bit_flipped",
        "missing",
        "larger_source_map",
        "tabular_for_dqn",
        "other_hidden",
    ],
)
def test_cli_refuses_bad_source_with_one_line(cli_refusals, case):
    results, _, _ = cli_refusals
    result, words = results[case]
    assert result.returncode != 0, result.output
    assert "Traceback" not in result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    for word in words:
        assert word in lines[0], lines[0]
    checkpoints = result.run_dir / "checkpoints"
    assert not checkpoints.exists() or not any(checkpoints.iterdir())
    assert not (result.run_dir / "metrics.jsonl").exists() and not (result.run_dir / "tb").exists()


@pytest.mark.slow
def test_planted_pickle_never_runs(cli_refusals):
    _, marker, planted = cli_refusals
    assert not marker.exists()  # the CLI refused the file without unpickling it
    # ...and the plant is live: unpickling it really would have created the marker.
    pickle.loads(planted).close()
    assert marker.exists()
    marker.unlink()


@pytest.mark.parametrize("protocol", range(pickle.HIGHEST_PROTOCOL + 1))
def test_planted_pickle_of_any_protocol_is_refused_in_process(work, protocol):
    """Old protocols do not start with the 0x80 opcode; they must be refused all the same."""
    marker = work / f"PWNED_{protocol}"
    source = work / f"plant_{protocol}" / "agent_0.safetensors"
    source.parent.mkdir()
    source.write_bytes(pickle.dumps(_Plant(str(marker)), protocol=protocol))
    trainer = make_trainer(
        make_config(TEAM_MAP, DQN_AGENT, transfer=TransferConfig(enabled=True, source=str(source))),
        work / f"plant_run_{protocol}",
        work,
    )
    with pytest.raises(CheckpointError, match="not a safetensors|pickle"):
        trainer.run()
    assert not marker.exists()
    assert not (work / f"plant_run_{protocol}" / "checkpoints").exists()


def test_out_of_range_targets_and_freeze_are_clear_errors(work, dqn_source):
    def run(name: str, **transfer) -> None:
        config = make_config(
            TEAM_MAP, DQN_AGENT, transfer=TransferConfig(enabled=True, source=str(dqn_source), **transfer)
        )
        make_trainer(config, work / name, work).run()

    with pytest.raises(TransferError, match=r"transfer.targets \[2\] out of range for 2 agents"):
        run("bad_targets", targets=[0, 2])
    with pytest.raises(ConfigError, match=r"transfer.freeze=\[3\].*3 layers"):  # refused before any work
        run("bad_freeze", freeze=[3])


# ------------------------------------------------------------------------- pretraining and its cache


def test_pretrained_source_is_cached_and_reused(work, caplog):
    caplog.set_level(logging.INFO, logger="dqn_transfer")
    cache = work / "cache"

    def run(name: str, pretrain_steps: int) -> Trainer:
        transfer = TransferConfig(enabled=True, cache_dir=str(cache), pretrain_steps=pretrain_steps)
        trainer = make_trainer(make_config(TEAM_MAP, DQN_AGENT, total_steps=5, transfer=transfer), work / name, work)
        trainer.run()
        return trainer

    first = run("cache_1", 120)
    entries = [e for e in cache.iterdir() if not e.name.startswith(".")]  # the lock files are hidden
    assert len(entries) == 1
    checkpoint = entries[0] / "checkpoints" / "agent_0.safetensors"
    assert "pretraining a source agent" in caplog.text and "reusing" not in caplog.text
    meta = header_meta(checkpoint)
    assert meta["steps"] == 120 and meta["source_task"]
    stamp, digest = checkpoint.stat().st_mtime_ns, meta["digest"]
    assert (
        first.replicas[0].transfer_info["source"] == str(checkpoint.resolve())
        and first.replicas[0].transfer_info["pretrained"]
    )

    caplog.clear()
    second = run("cache_2", 120)
    assert "reusing the pretrained source" in caplog.text and "pretraining a source agent" not in caplog.text
    assert checkpoint.stat().st_mtime_ns == stamp and header_meta(checkpoint)["digest"] == digest
    assert second.replicas[0].transfer_info["digest"] == digest

    caplog.clear()
    third = run("cache_3", 140)  # another source config: another cache entry, the first untouched
    assert "pretraining a source agent" in caplog.text
    assert len([e for e in cache.iterdir() if not e.name.startswith(".")]) == 2
    assert checkpoint.stat().st_mtime_ns == stamp
    assert (
        third.replicas[0].transfer_info["digest"] != digest
        and header_meta(Path(third.replicas[0].transfer_info["source"]))["steps"] == 140
    )


def test_relative_cache_dir_is_under_the_launch_dir(work, monkeypatch):
    """Like a relative transfer.source: under the launch dir, not wherever the process runs
    (hydra.job.chdir=true, SLURM jobs), else every run would pretrain into its own cache."""
    launch, elsewhere = work / "launch", work / "elsewhere"
    launch.mkdir()
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    transfer = TransferConfig(enabled=True, cache_dir="rel_cache", pretrain_steps=20)
    trainer = make_trainer(make_config(TEAM_MAP, QL_AGENT, transfer=transfer), work / "rel_run", launch)
    trainer.run()
    assert Path(trainer.replicas[0].transfer_info["source"]).is_relative_to(launch / "rel_cache")
    assert not (elsewhere / "rel_cache").exists()


# ------------------------------------------------------------------------------------ jumpstart

SEEDS = (0, 1, 2)


def _jumpstart_runs(work: Path, name: str, agent: dict, transfer: TransferConfig):
    on, off = [], []
    for seed in SEEDS:
        for condition, dirs, t in (("on", on, transfer), ("off", off, TransferConfig())):
            run_dir = work / f"js_{name}_{condition}_{seed}"
            config = make_config(SOLO_MAP, agent, seed=seed, total_steps=1, transfer=t, eval_episodes=2)
            make_trainer(config, run_dir, work).run()
            dirs.append(run_dir)
    return on, off


def _step0_team_return(run_dir: Path) -> float:
    first = json.loads((run_dir / "metrics.jsonl").read_text().splitlines()[0])
    assert first["step"] == 0
    return first["team_return"]


def _check_jumpstart(on, off, label: str):
    transferred = [_step0_team_return(d) for d in on]
    baseline = [_step0_team_return(d) for d in off]
    results = compare_runs(on, off)
    js = results["jumpstart"]
    print(
        f"[{label}] step-0 team_return transfer={transferred} baseline={baseline} "  # shown with -s
        f"jumpstart mean={js['mean']:.2f} 95% CI=[{js['low']:.2f}, {js['high']:.2f}] n={js['n']}"
    )
    # The source solves the map (chest 4 moves away: 3 x -1 + 100), and the transfer keeps its policy.
    assert transferred == [97.0] * len(SEEDS)
    assert js["n"] == len(SEEDS) and js["mean"] > 0 and js["low"] > 0
    for t, b in zip(on, off):
        assert jumpstart(learning_curve(t), learning_curve(b)) > 0
    return js


@pytest.mark.slow
def test_jumpstart_tabular_with_pretrained_sources(work):
    # The real `transfer=on` path: no source given, each seed pretrains (and caches) its own.
    transfer = TransferConfig(enabled=True, cache_dir=str(work / "js_cache"), pretrain_steps=1_500)
    on, off = _jumpstart_runs(work, "ql", QL_AGENT, transfer)
    for run_dir in on:
        source = Path(json.loads((run_dir / "metrics.jsonl").read_text().splitlines()[0])["transfer_source"]["source"])
        assert header_meta(source)["last_eval"]["success_rate"] == 1.0  # the source task is solved
    _check_jumpstart(on, off, "qlearning")


@pytest.mark.slow
def test_jumpstart_dqn(work):
    source = train_source(work / "js_dqn_source", SOLO_MAP, {**DQN_AGENT, "learning_starts": 100}, 800, eval_episodes=1)
    assert header_meta(source)["last_eval"]["success_rate"] == 1.0
    on, off = _jumpstart_runs(work, "dqn", DQN_AGENT, TransferConfig(enabled=True, source=str(source)))
    _check_jumpstart(on, off, "dqn")


# ------------------------------------------------------------------------ what a run records


def test_run_records_source_path_and_digest(work, dqn_source):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir = work / "records"
    config = make_config(
        TEAM_MAP, DQN_AGENT, total_steps=3, transfer=TransferConfig(enabled=True, source=str(dqn_source))
    )
    make_trainer(config, run_dir, work).run()
    digest = header_meta(dqn_source)["digest"]

    first = json.loads((run_dir / "metrics.jsonl").read_text().splitlines()[0])
    assert first["step"] == 0
    assert first["transfer_source"]["source"] == str(dqn_source.resolve())
    assert first["transfer_source"]["digest"] == digest
    later = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()[1:]]
    assert later and all("transfer_source" not in record for record in later)

    events = EventAccumulator(str(run_dir / "tb"), size_guidance={"tensors": 0})
    events.Reload()
    assert "transfer/source" in events.Tags()["tensors"]
    text = events.Tensors("transfer/source")[0].tensor_proto.string_val[0].decode()
    assert str(dqn_source.resolve()) in text and digest in text
    # The run's own checkpoints say where they came from too.
    assert header_meta(run_dir / "checkpoints" / "agent_0.safetensors")["transfer"]["digest"] == digest


# ------------------------------------------------------------------- targets, freeze, exchange


def test_targets_transfers_only_the_listed_agents(work, dqn_source):
    source = load_file(str(dqn_source))
    on = make_trainer(
        make_config(
            TEAM_MAP, DQN_AGENT, seed=7, transfer=TransferConfig(enabled=True, source=str(dqn_source), targets=[0])
        ),
        work / "targets_on",
        work,
    )
    off = make_trainer(make_config(TEAM_MAP, DQN_AGENT, seed=7), work / "targets_off", work)
    on.run()
    off.run()
    assert on.replicas[0].transfer_info["targets"] == [0]
    assert on.replicas[0].transferred.tolist() == [True, False]
    agent0, agent1 = on.learner.agent_tensors(0), on.learner.agent_tensors(1)
    fresh0, fresh1 = off.learner.agent_tensors(0), off.learner.agent_tensors(1)
    for name in fresh1:  # agent 1 keeps its random init: identical to the same seed without transfer
        np.testing.assert_array_equal(agent1[name], fresh1[name])
    np.testing.assert_array_equal(agent0["q.layers.0.weight"][:, : N * N], source["q.layers.0.weight"])
    assert not agent0["q.layers.0.weight"][:, N * N :].any()  # treasures: zero input weights
    np.testing.assert_array_equal(agent0["q.layers.2.weight"], source["q.layers.2.weight"])
    assert not np.array_equal(agent0["q.layers.2.weight"], fresh0["q.layers.2.weight"])


def test_freeze_keeps_layer_0_fixed_while_training(work, dqn_source):
    source = load_file(str(dqn_source))
    config = make_config(
        TEAM_MAP, DQN_AGENT, total_steps=150, transfer=TransferConfig(enabled=True, source=str(dqn_source), freeze=[0])
    )
    trainer = make_trainer(config, work / "freeze", work)
    trainer.run()
    assert trainer.learner.num_gradient_steps >= 90
    for agent in range(2):
        tensors = trainer.learner.agent_tensors(agent)
        np.testing.assert_array_equal(tensors["q.layers.0.weight"][:, : N * N], source["q.layers.0.weight"])
        assert not tensors["q.layers.0.weight"][:, N * N :].any()
        np.testing.assert_array_equal(tensors["q.layers.0.bias"], source["q.layers.0.bias"])
        assert not np.array_equal(tensors["q.layers.1.weight"], source["q.layers.1.weight"])  # the rest learned
    saved = load_file(str(trainer.replicas[0].run_dir.agent_checkpoint(1)))
    np.testing.assert_array_equal(saved["q.layers.0.bias"], source["q.layers.0.bias"])


def _flat(weights: dict[str, np.ndarray]) -> np.ndarray:
    return np.concatenate([weights[name].ravel() for name in sorted(weights)])


def test_exchange_best_moves_others_towards_the_best(work, dqn_source, monkeypatch):
    import dqn_transfer.exchange.best as best_module

    real = best_module.exchange_best
    calls = []

    def spy(team, window_returns, tau):
        learner = trainer.learner  # the team's rows (one replica: all of them)
        before = [_flat(learner.get_member_weights(i)) for i in range(team.num_agents)]
        best = real(team, window_returns, tau)
        after = [_flat(learner.get_member_weights(i)) for i in range(team.num_agents)]
        calls.append((np.array(window_returns), tau, best, before, after))
        return best

    monkeypatch.setattr(best_module, "exchange_best", spy)
    # Only agent 0 is transferred, so the two networks differ from the start.
    transfer = TransferConfig(
        enabled=True, source=str(dqn_source), targets=[0], exchange=Exchange.best, exchange_every=3, exchange_tau=0.25
    )
    trainer = make_trainer(make_config(TEAM_MAP, DQN_AGENT, total_steps=300, transfer=transfer), work / "best", work)
    trainer.run()
    assert len(calls) == trainer.replicas[0].counters.episodes // 3 >= 3
    for window_returns, tau, best, before, after in calls:
        assert tau == 0.25 and window_returns.shape == (3, 2)
        assert best == int(np.argmax(window_returns.mean(axis=0)))
        other = 1 - best
        assert np.array_equal(after[best], before[best])
        np.testing.assert_allclose(after[other], 0.75 * before[other] + 0.25 * before[best], rtol=1.3e-6, atol=1e-5)
        gap_before = np.linalg.norm(before[other] - before[best])
        assert np.linalg.norm(after[other] - before[best]) < gap_before


def test_shared_replay_gives_each_agent_its_teammates_transitions(work, dqn_source, monkeypatch):
    import dqn_transfer.exchange.shared_replay as shared_replay_module

    real = shared_replay_module.exchange_replay
    calls = []

    def spy(team, transitions, bounced):
        replay = trainer.learner.replay  # the team's rows (one replica: all of them)
        size_before = replay.size.copy()
        assert not np.any(bounced)  # TEAM_MAP has no obstacle: every transition is shared
        real(team, transitions, bounced)
        calls.append(
            (
                size_before,
                replay.size.copy(),
                list(transitions),
                replay.ptr.copy(),
                torch.from_numpy(replay.state_dict()["obs"]),
            )
        )

    monkeypatch.setattr(shared_replay_module, "exchange_replay", spy)
    transfer = TransferConfig(enabled=True, source=str(dqn_source), exchange=Exchange.shared_replay, exchange_every=2)
    trainer = make_trainer(make_config(TEAM_MAP, DQN_AGENT, total_steps=300, transfer=transfer), work / "shared", work)
    trainer.run()
    assert len(calls) == trainer.replicas[0].counters.episodes // 2 >= 3
    shared_total = np.zeros(2, dtype=np.int64)
    for size_before, size_after, transitions, ptr, obs_storage in calls:
        live = np.stack([t[6] for t in transitions])  # live_before, [steps, K]
        own_obs = np.stack([t[0] for t in transitions])  # [steps, K, D]
        for receiver in range(2):
            giver = 1 - receiver
            given = int(live[:, giver].sum())
            assert given > 0
            assert size_after[receiver] - size_before[receiver] == given  # buffer far from full
            # The newest `given` rows of the receiver are exactly the teammate's observations.
            newest = obs_storage[receiver, ptr[receiver] - given : ptr[receiver]].numpy()
            np.testing.assert_array_equal(newest, own_obs[live[:, giver], giver])
            shared_total[receiver] += given
    # Over the run: own transitions (one per live step) + what the teammate shared.
    own = trainer.learner.replay.size - shared_total
    assert (own > 0).all() and (own <= trainer.replicas[0].counters.step).all()


# ----------------------------------------------------------------------------- optimizer carry-over


def test_reset_optimizer_false_carries_the_sources_adam_moments(work, dqn_source):
    """Moments come from the source's resume state; layer 0's rows map like its weights."""
    source_state = load_file(str(dqn_source.parent / "training_state.safetensors"))
    config = make_config(
        TEAM_MAP, DQN_AGENT, transfer=TransferConfig(enabled=True, source=str(dqn_source), reset_optimizer=False)
    )
    trainer = make_trainer(config, work / "carry_adam", work)
    trainer.run()
    state, _ = trainer.learner.training_state()  # weight_0 moments [K, in, out]: rows 0..24 position, 25..26 treasures
    for key in ("exp_avg", "exp_avg_sq"):
        source_moment = source_state[f"learner/optim.weight_0.{key}"][0]  # [25, 32]
        carried = state[f"optim.weight_0.{key}"]
        for agent in (0, 1):
            np.testing.assert_array_equal(carried[agent, : N * N], source_moment)
            assert np.count_nonzero(carried[agent, N * N :]) == 0  # treasures rows: no history
            np.testing.assert_array_equal(
                state[f"optim.bias_1.{key}"][agent], source_state[f"learner/optim.bias_1.{key}"][0]
            )
    assert float(state["optim.weight_0.step"]) == float(source_state["learner/optim.weight_0.step"].reshape(-1)[0])


def test_reset_optimizer_false_refuses_partial_targets(work, dqn_source):
    config = make_config(
        TEAM_MAP,
        DQN_AGENT,
        transfer=TransferConfig(enabled=True, source=str(dqn_source), reset_optimizer=False, targets=[1]),
    )
    with pytest.raises(TransferError, match="needs every agent as a target"):
        make_trainer(config, work / "carry_adam_partial", work).run()


def test_reset_optimizer_false_needs_the_sources_resume_state(work, dqn_source):
    lone = work / "lone" / "agent_0.safetensors"
    lone.parent.mkdir(exist_ok=True)
    lone.write_bytes(dqn_source.read_bytes())
    config = make_config(
        TEAM_MAP, DQN_AGENT, transfer=TransferConfig(enabled=True, source=str(lone), reset_optimizer=False)
    )
    with pytest.raises(TransferError, match="needs the source's optimizer state"):
        make_trainer(config, work / "carry_adam_lone", work).run()
