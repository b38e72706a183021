"""The benchmark (``dqn_transfer.benchmark``, ``dqn-transfer-bench``) at tiny sizes.

No timing assertions (the machine may be shared): the tests pin what each measurement counts and
subtracts, that both contenders get the same hyperparameters and play the same episodes, how figures
are summarised, what the table holds and how the command line refuses bad input. The whole-process
sections (5, 6) start real processes at tiny sizes and check what they did (steps, gradient steps,
replica directories), never how fast.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import statistics
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from torch import nn

from dqn_transfer.agents import DQNLearner, make_learner
from dqn_transfer.benchmark import game_batches, processes, suite, tables, tabular_batches, whole_process
from dqn_transfer.benchmark.config import (
    BENCH_AGENT,
    BENCH_MAP,
    LONE_AGENT,
    LONE_MAP,
    SB3_NAMES,
    SOURCE_MAP,
    TEAM_MAP,
    replay_warmup,
    sb3_dqn,
    sb3_kwargs,
)
from dqn_transfer.benchmark.env_throughput import measure_env_throughput
from dqn_transfer.benchmark.team_scaling import TeamRig
from dqn_transfer.benchmark.training import greedy_check, measure_training
from dqn_transfer.benchmark.update_cost import SB3UpdateRig, UpdateRig
from dqn_transfer.cli import bench as cli
from dqn_transfer.config import CONFIG_DIR, AgentConfig, TrainConfig, register_configs
from dqn_transfer.config.overrides import check_overrides
from dqn_transfer.enums import Algorithm
from dqn_transfer.envs import make_game

TINY = dataclasses.replace(BENCH_AGENT, batch_size=8, buffer_size=200, learning_starts=20, target_update=10, hidden=[8])
TINY_MAP = {**SOURCE_MAP, "max_steps": 10}
TINY_SIZES = suite.Sizes(env_steps=20, train_steps=30, team_steps=2, updates=2, eval_episodes=1, thread_cap_s=0.05)
TRAIN_STEPS = 40
IN_PROCESS = ("env", "training", "team", "update")
# Sections 5 and 6: 1,100 steps is 25 gradient steps after LONE_AGENT's learning_starts of 1,000; 60 steps
# with learning_starts 20 is 10.
PROCESS_SIZES = dataclasses.replace(
    TINY_SIZES, lone_steps=1_100, replica_steps=60, replica_counts=(1, 2), replica_learning_starts=20
)


def gradient_steps(steps: int, learning_starts: int, train_freq: int) -> int:
    """Updates of a run of ``steps`` env steps: at every step > learning_starts divisible by train_freq."""
    return steps // train_freq - learning_starts // train_freq


# ----------------------------------------------------------------------------- matched hyperparameters
def test_sb3_kwargs_give_sb3_our_values_under_its_names():
    assert sb3_kwargs(BENCH_AGENT) == {
        "learning_rate": 1e-3,
        "gamma": 0.99,
        "batch_size": 64,
        "buffer_size": 50_000,
        "learning_starts": 1_000,
        "train_freq": 1,
        "gradient_steps": 1,
        "target_update_interval": 500,
        "tau": 1.0,
        "max_grad_norm": 10.0,
        "exploration_initial_eps": 1.0,
        "exploration_final_eps": 0.05,
        "exploration_fraction": 0.5,
        "policy_kwargs": {"net_arch": [64, 64]},
        "device": "cpu",
    }
    # Every hyperparameter the DQN learner and the trainer read is matched (a new key must be added).
    # hidden: net_arch; the others fixed (engine: what computes ours, not a hyperparameter; agent_id_input and
    # the team's mixer off: the benchmark's task has one agent)
    matched = {*SB3_NAMES, "hidden", "algorithm", "share_parameters", "agent_id_input", "mixer", "engine"}
    assert matched == {field.name for field in dataclasses.fields(AgentConfig)}
    model = sb3_dqn(TINY, TINY_MAP, seed=0)  # and SB3 keeps them as given
    assert (model.batch_size, model.buffer_size, model.learning_starts) == (8, 200, 20)
    assert model.target_update_interval == 10
    assert (model.tau, model.gamma, model.max_grad_norm) == (1.0, 0.99, 10.0)
    hidden = [layer.out_features for layer in model.q_net.q_net if isinstance(layer, nn.Linear)][:-1]
    assert hidden == [8]


def test_bench_learner_differs_from_the_cli_learner_only_in_the_overridden_keys():
    game = make_game(**SOURCE_MAP).single_agent_game()
    cli_agent = AgentConfig(algorithm=Algorithm.dqn)
    learners = {
        id(config): make_learner(config, 1, game.obs_layout(), game.num_actions, seed=0)
        for config in (BENCH_AGENT, cli_agent)
    }
    field_of = {
        "lr": "lr",
        "gamma": "gamma",
        "batch_size": "batch_size",
        "learning_starts": "learning_starts",
        "train_freq": "train_freq",
        "gradient_steps": "gradient_steps",
        "target_update": "target_update",
        "tau": "tau",
        "hidden": "hidden",
        "max_grad_norm": "max_grad_norm",
        "replay.capacity": "buffer_size",
    }
    differing = set()
    for attribute, field in field_of.items():
        values = []
        for config in (BENCH_AGENT, cli_agent):
            value = functools.reduce(getattr, attribute.split("."), learners[id(config)])
            assert value == getattr(config, field), (attribute, config)
            values.append(value)
        if values[0] != values[1]:
            differing.add(field)
    assert differing == {"target_update", "tau"}
    for key in ("eps_start", "eps_end", "exploration_fraction"):  # the trainer's schedule, SB3's too
        assert getattr(BENCH_AGENT, key) == getattr(cli_agent, key)


# ----------------------------------------------------------------------------- summarising repeats
def test_a_ratio_is_the_median_of_the_per_repeat_ratios():
    ours, reference = [2.0, 9.0, 4.0], [1.0, 3.0, 1.0]  # per-repeat ratios 2, 3, 4
    assert suite.paired_ratio(ours, reference) == 3.0
    assert statistics.median(ours) / statistics.median(reference) == 4.0  # what a ratio of medians would say
    assert suite.alternate(("ours", "sb3"), 0) == ("ours", "sb3")
    assert suite.alternate(("ours", "sb3"), 1) == ("sb3", "ours")


# ----------------------------------------------------------------------------- 1. environment
def test_env_throughput_plays_the_same_episodes_through_both_paths():
    result = measure_env_throughput(2, 300, seed=0)
    assert result["steps"] == 300
    assert result["pettingzoo_episodes"] == result["core_episodes"] >= 2  # 100-step episodes at most


# ----------------------------------------------------------------------------- 2. training
@pytest.fixture(scope="module")
def training_runs():
    return {who: measure_training(who, TRAIN_STEPS, 0, TINY, TINY_MAP, eval_episodes=2) for who in ("ours", "sb3")}


def test_both_contenders_take_one_gradient_step_per_env_step_after_learning_starts(training_runs):
    for result in training_runs.values():
        assert result["steps"] == TRAIN_STEPS
        assert result["gradient_steps"] == TRAIN_STEPS - TINY.learning_starts
        assert result["greedy_success"] in (0.0, 0.5, 1.0)


def test_our_training_time_excludes_the_trainers_evaluations_and_checkpoints(training_runs):
    ours = training_runs["ours"]
    assert ours["excluded_seconds"] > 0
    assert 0 < ours["seconds"] < ours["run_seconds"]
    assert ours["seconds"] + ours["excluded_seconds"] == pytest.approx(ours["run_seconds"])
    assert ours["steps_per_s"] == pytest.approx(TRAIN_STEPS / ours["seconds"])


def test_greedy_check_plays_the_episodes_of_treasure_hunt_v0():
    def walk(obs: np.ndarray) -> int:  # a deterministic policy that moves around the map
        return int(np.argmax(obs)) % 4

    env = gymnasium.make("TreasureHunt-v0", **SOURCE_MAP)
    returns, found = [], []
    for episode in range(2):
        obs, _ = env.reset(seed=7 + episode)
        done, total, got = False, 0.0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(walk(obs))
            total, got, done = total + reward, got or info["treasures_collected"] > 0, terminated or truncated
        returns.append(total)
        found.append(got)
    result = greedy_check(lambda obs, live: np.array([walk(obs[0])]), SOURCE_MAP, episodes=2, seed=7)
    assert result == {"greedy_success": float(np.mean(found)), "greedy_return": float(np.mean(returns))}


# ----------------------------------------------------------------------------- 3. team size
def test_team_rigs_batched_is_one_learner_of_k_and_both_play_the_same_steps():
    batched, separate = TeamRig(3, False, 0, TINY), TeamRig(3, True, 0, TINY)
    assert len(batched.learners) == 1 and isinstance(batched.learners[0], DQNLearner)
    assert batched.learners[0].num_agents == 3 and batched.learners[0].q_network.num_members == 3
    assert [learner.num_agents for learner in separate.learners] == [1, 1, 1]
    for rig in (batched, separate):
        assert rig.step_count == TINY.learning_starts  # replay filled, untimed, without training
        assert all(learner.num_gradient_steps == 0 for learner in rig.learners)
        rig.run(4)
        assert rig.step_count == TINY.learning_starts + 4
        assert all(learner.num_gradient_steps == 4 for learner in rig.learners)  # every timed step trains


# ----------------------------------------------------------------------------- 4. gradient update
def test_update_rig_times_real_updates_on_real_replay():
    rig = UpdateRig(0, TINY, TINY_MAP)
    assert rig.learner.replay.size.tolist() == [replay_warmup(TINY)]
    rig.time("ours", 3)
    assert rig.learner.num_gradient_steps == 1 + 3  # one untimed warm-up call, then the timed ones
    before = [p.detach().clone() for p in rig.q.parameters()]
    rig.time("bare", 2)
    assert all(not torch.equal(a, b) for a, b in zip(before, rig.q.parameters()))


def test_the_bare_update_and_ours_are_the_same_update():
    rig = UpdateRig(0, TINY, TINY_MAP)
    linears = [layer for layer in rig.q if isinstance(layer, nn.Linear)]
    state = {
        f"layers.{l}.{kind}": getattr(layer, kind).detach().clone()
        for l, layer in enumerate(linears)
        for kind in ("weight", "bias")
    }
    rig.learner.load_agent_tensors(0, {f"q.{name}": t.numpy() for name, t in state.items()})
    rig.bare_update()
    rig.learner.train_on(rig.batch)
    updated = {
        f"layers.{l}.{kind}": getattr(layer, kind).detach()
        for l, layer in enumerate(linears)
        for kind in ("weight", "bias")
    }
    for name, tensor in rig.learner.get_member_weights(0).items():
        assert not np.array_equal(tensor, state[name]), name  # it moved
        np.testing.assert_allclose(tensor, updated[name], rtol=0, atol=1e-6, err_msg=name)


def test_sb3_update_rig_fills_replay_without_training_then_times_train():
    rig = SB3UpdateRig(0, TINY, TINY_MAP)
    assert rig.model._n_updates == 0 and rig.model.replay_buffer.size() == replay_warmup(TINY)
    rig.time(2)
    assert rig.model._n_updates == 1 + 2


# ----------------------------------------------------------------------------- 5. and 6. whole processes
def compose_train_command(command: list[str]) -> TrainConfig:
    """The config ``python -m dqn_transfer.cli.train`` composes from ``command``'s overrides."""
    assert command[:3] == [sys.executable, "-m", "dqn_transfer.cli.train"]
    overrides = command[3:]
    check_overrides(overrides)  # every key is in the schema (else ConfigError)
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[o for o in overrides if not o.startswith("hydra.")])
    return OmegaConf.to_object(cfg)


def test_our_lone_process_gets_exactly_the_lone_settings(tmp_path):
    command = whole_process.train_command(tmp_path / "run", 2_000, 3, LONE_AGENT, {**LONE_MAP, "num_agents": 1})
    # The settings the benchmark promises, spelt as on a command line.
    for override in (
        "env.size=7",
        "env.num_treasures=1",
        "env.num_traps=1",
        "env.complexity=0.15",
        "env.map_seed=3",
        "env.num_agents=1",
        "agent=dqn",
        "agent.hidden=[64,64]",
        "agent.batch_size=32",
        "agent.train_freq=4",
        "agent.gradient_steps=1",
        "agent.target_update=1000",
        "agent.tau=1.0",
        "agent.buffer_size=50000",
        "agent.lr=0.0001",
        "agent.learning_starts=1000",
        "total_steps=2000",
        "eval_every=2000",
        "eval_episodes=1",
        "checkpoint_every=2000",
        "progress=false",
        "threads=1",
        f"hydra.run.dir={tmp_path / 'run'}",
    ):
        assert override in command, override
    config = compose_train_command(command)
    assert config.agent == LONE_AGENT  # every key, the unlisted ones (gamma, epsilon, clip) included
    assert {key: getattr(config.env, key) for key in LONE_MAP} == LONE_MAP and config.env.num_agents == 1
    assert (config.seed, config.total_steps, config.threads, config.replicas.seeds) == (3, 2_000, 1, 1)
    # SB3 and bare get the same values (SB3 under its own names).
    assert sb3_kwargs(LONE_AGENT)["learning_rate"] == 1e-4 and sb3_kwargs(LONE_AGENT)["target_update_interval"] == 1_000


def test_our_replicas_process_is_a_cooperative_team_of_four_on_the_bench_map(tmp_path):
    agent = dataclasses.replace(LONE_AGENT, learning_starts=500)
    command = whole_process.train_command(tmp_path / "run", 300, 0, agent, TEAM_MAP, threads=2, replicas=16)
    config = compose_train_command(command)
    assert config.agent == agent
    assert {key: getattr(config.env, key) for key in BENCH_MAP} == BENCH_MAP
    assert (config.env.num_agents, config.env.mode.value) == (4, "cooperative")
    assert (config.replicas.seeds, config.replicas.maps, config.threads) == (16, 1, 2)


@pytest.mark.parametrize("program", ["sb3", "bare"])
def test_reference_programs_train_on_schedule(program):
    agent = dataclasses.replace(LONE_AGENT, learning_starts=20, buffer_size=100)
    report = processes.PROGRAMS[program](60, 0, agent, LONE_MAP)
    assert report["steps"] == 60
    assert report["gradient_steps"] == gradient_steps(60, 20, LONE_AGENT.train_freq) == 10
    assert report["episodes"] >= 1  # 49-step episodes at most on the 7 x 7 map


def test_the_bare_loop_decays_epsilon_as_cleanrl_does():
    assert processes.linear_schedule(1.0, 0.05, 100, 0) == 1.0
    assert processes.linear_schedule(1.0, 0.05, 100, 50) == pytest.approx(0.525)
    assert processes.linear_schedule(1.0, 0.05, 100, 500) == 0.05


def test_run_together_times_each_process_and_reads_its_last_line():
    script = "import json, time; time.sleep({}); print('log line'); print(json.dumps({{'slept': {}}}))"
    out = whole_process.run_together(
        [[sys.executable, "-c", script.format(0.2, 0.2)], [sys.executable, "-c", script.format(0.4, 0.4)]]
    )
    assert [p["report"] for p in out["processes"]] == [{"slept": 0.2}, {"slept": 0.4}]
    assert out["seconds"] >= max(p["seconds"] for p in out["processes"])  # first spawn to last exit
    assert out["cpu_seconds"] == pytest.approx(sum(p["cpu_seconds"] for p in out["processes"]))
    assert all(p["cpu_seconds"] > 0 and p["max_rss_mb"] > 1 for p in out["processes"])  # the child's, via wait4
    with pytest.raises(whole_process.ProcessFailed, match="exited with 3:\nno good"):
        whole_process.run_together(
            [[sys.executable, "-c", "import sys; print('no good', file=sys.stderr); sys.exit(3)"]]
        )


def test_processes_command_line_prints_what_it_did(capsys):
    threads = torch.get_num_threads()
    try:
        assert (
            processes.main(["bare", "--steps", "30", "--seed", "1", "--map", "bench", "--learning-starts", "10"]) == 0
        )
    finally:
        torch.set_num_threads(threads)  # main sets one thread, as its own process would
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(report) == {"program", "steps", "gradient_steps", "episodes"}
    assert (report["program"], report["steps"], report["gradient_steps"]) == ("bare", 30, gradient_steps(30, 10, 4))


@pytest.fixture(scope="module")
def process_document():
    return suite.run_benchmark(
        "quick", 0, 1, 1, sizes=PROCESS_SIZES, sections=("lone", "replicas"), progress=lambda what: None
    )


@pytest.mark.slow
def test_lone_section_runs_four_whole_processes_that_train(process_document):
    lone = process_document["lone"]
    contenders = lone["contenders"]
    assert set(contenders) == {"ours", "ours_torch", "sb3", "bare"} and lone["steps"] == PROCESS_SIZES.lone_steps
    expected = gradient_steps(PROCESS_SIZES.lone_steps, LONE_AGENT.learning_starts, LONE_AGENT.train_freq)
    for who, runs in ((who, c["raw"]) for who, c in contenders.items()):
        assert len(runs) == 1
        assert runs[0]["steps_done"] == PROCESS_SIZES.lone_steps, who
        assert runs[0]["gradient_steps"] == expected == 25, who
        assert runs[0]["cpu_seconds"] > 0 and runs[0]["max_rss_mb"] > 0
    assert contenders["ours"]["ours_over_this"] == 1.0
    assert contenders["sb3"]["figures"]["gradient_steps"] == expected
    assert lone["hyperparameters"] == {
        **dataclasses.asdict(LONE_AGENT),
        "algorithm": "dqn",
        "engine": "auto",
        "mixer": "none",
    }
    assert len(lone["load"]["start"]) == len(lone["load"]["end"]) == 3


@pytest.mark.slow
def test_replicas_section_runs_one_process_of_r_replicas_and_sb3_side_by_side(process_document):
    rep = process_document["replicas"]
    cores = process_document["machine"]["cpus_available"]
    expected = gradient_steps(PROCESS_SIZES.replica_steps, PROCESS_SIZES.replica_learning_starts, 4)
    assert [(row["engine"], row["replicas"]) for row in rep["rows"]] == [
        ("numpy", 1),
        ("numpy", 2),
        ("torch", 1),
        ("torch", 2),
    ]
    for row in rep["rows"]:
        run = row["raw"][0]
        assert row["learners"] == run["learners"] == 4 * row["replicas"]
        assert run["replica_dirs"] == row["replicas"]  # R=2: seed_0/ and seed_1/, each a complete run
        assert run["replica_steps"] == [PROCESS_SIZES.replica_steps] * row["replicas"]
        assert run["gradient_steps"] == expected == 10
        assert run["threads"] == 1
        assert run["learner_steps_per_s"] == pytest.approx(4 * row["replicas"] * rep["steps"] / run["seconds"])
    sb3 = rep["sb3_raw"][0]
    assert sb3["processes"] == rep["sb3_processes"] == cores
    assert sb3["process_steps"] == [rep["steps"]] * cores and sb3["gradient_steps"] == [expected] * cores
    assert sb3["learner_steps_per_s"] == pytest.approx(cores * rep["steps"] / sb3["seconds"])
    assert sb3["seconds"] >= max(sb3["process_seconds"])  # until the last one exits
    assert rep["hyperparameters"]["learning_starts"] == PROCESS_SIZES.replica_learning_starts
    assert process_document["settings"]["sizes"]["replica_counts"] == [1, 2]
    assert json.loads(json.dumps(process_document)) == process_document


@pytest.mark.slow
def test_tables_of_the_whole_process_sections(process_document):
    table = tables.render_markdown(process_document)
    assert [line.split()[1] for line in table.splitlines() if line.startswith("## ")] == ["5.", "6."]
    assert [row.split(":")[0] for row in table_rows(table, "## 5.")] == [
        "ours",
        "ours, torch engine",
        "SB3",
        "bare PyTorch",
    ]
    assert table_rows(table, "## 6.") == ["numpy", "numpy", "torch", "torch"]
    for heading in ("## 5.", "## 6."):
        part = table.split(heading, 1)[1].split("\n## ", 1)[0]
        assert process_document["machine"]["cpu_model"] in part
        assert "at the start of this section" in part and "at its end" in part
        assert "Settings:" in part and "batch 32" in part and "lr 0.0001" in part


# ----------------------------------------------------------------------------- the document and its table
@pytest.fixture(scope="module")
def document():
    return suite.run_benchmark(
        "quick", 0, 1, 1, sizes=TINY_SIZES, agent=TINY, sections=IN_PROCESS, progress=lambda what: None
    )


def table_rows(table: str, heading: str) -> list[str]:
    """First cells of the data rows of the part under ``heading``."""
    part = table.split(heading, 1)[1].split("\n## ", 1)[0]
    return [line.split("|")[1].strip() for line in part.splitlines() if line.startswith("| ") and "---" not in line][1:]


def test_document_holds_every_section_and_is_json(document):
    assert [row["num_agents"] for row in document["env"]] == list(suite.ENV_AGENTS)
    assert [row["num_agents"] for row in document["team"]] == list(suite.TEAM_SIZES)
    assert [row["torch_threads"] for row in document["training"]] == [1]
    for who in ("ours", "sb3"):
        assert [run["gradient_steps"] for run in document["training"][0]["raw"][who]] == [30 - TINY.learning_starts]
    timings = document["update"]["timings"]
    assert {"bare", "in_memory", "ours", "sample", "sb3"} <= set(timings)
    assert timings["bare"]["over_bare"] == 1.0
    assert ("ours_default_threads" in timings) == (suite.DEFAULT_THREADS != 1)
    assert document["settings"]["hyperparameters"] == {
        **dataclasses.asdict(TINY),
        "algorithm": "dqn",
        "engine": "auto",
        "mixer": "none",
    }
    assert document["machine"]["torch_threads_used"] == [1]
    assert json.loads(json.dumps(document)) == document  # plain JSON types throughout


def test_table_has_the_four_sections_and_a_row_per_agent_count(document):
    table = tables.render_markdown(document)
    headings = [line for line in table.splitlines() if line.startswith("## ")]
    assert [h.split()[1] for h in headings] == ["1.", "2.", "3.", "4."]
    assert table_rows(table, "## 1.") == ["1", "4", "8"]
    assert table_rows(table, "## 2.") == ["1"]
    assert table_rows(table, "## 3.") == ["1", "2", "4", "8"]
    assert len(table_rows(table, "## 4.")) == 5 + 2 * ("ours_default_threads" in document["update"]["timings"])


# ----------------------------------------------------------------------------- the command line
def test_cli_prints_the_table_and_writes_the_document(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(suite.PROFILES, "quick", TINY_SIZES)
    out = tmp_path / "nested" / "bench.json"
    assert cli.main(["--quick", "--repeats", "1", "--only", "env", "--out", str(out)]) == 0
    stdout, stderr = capsys.readouterr()
    saved = json.loads(out.read_text())
    assert saved["markdown"].strip() == stdout.strip()
    assert "## 1." in stdout and "## 2." not in stdout and "env" in saved and "training" not in saved
    assert saved["settings"]["sizes"]["env_steps"] == TINY_SIZES.env_steps
    assert "env throughput" in stderr and f"wrote {out}" in stderr


def test_cli_profile_and_sections_choose_what_is_measured(tmp_path, monkeypatch, capsys):
    calls = []

    def fake_run(profile, seed, repeats, threads, sections, baseline):
        calls.append((profile, list(sections)))
        return suite.run_benchmark(
            profile, seed, repeats, threads, sizes=TINY_SIZES, sections=["env"], progress=lambda what: None
        )

    monkeypatch.setattr(cli, "run_benchmark", fake_run)
    out = str(tmp_path / "bench.json")
    for argv in (
        ["--profile", "quick", "--sections", "replicas,lone"],
        ["--quick", "--only", "lone", "--only", "replicas"],
    ):
        assert cli.main([*argv, "--repeats", "1", "--out", out]) == 0
    assert cli.main(["--sections", "update, env", "--only", "lone", "--out", out]) == 0
    assert cli.main(["--out", out]) == 0
    assert calls == [
        ("quick", ["lone", "replicas"]),
        ("quick", ["lone", "replicas"]),
        ("full", ["env", "update", "lone"]),
        ("full", list(suite.SECTIONS)),
    ]
    capsys.readouterr()


@pytest.mark.parametrize(
    "argv",
    [
        ["--repeats", "0"],
        ["--threads", "x"],
        ["--seed", "1.5"],
        ["--bogus"],
        ["--only", "everything"],
        ["--sections", "lone,bogus"],
        ["--sections", ","],
        ["--profile", "tiny"],
    ],
)
def test_bad_arguments_are_argparse_errors(argv, capsys):
    with pytest.raises(SystemExit) as excinfo:
        cli.main(argv)
    assert excinfo.value.code == 2
    assert "error:" in capsys.readouterr().err


@pytest.mark.parametrize("out", ["DIR", "/proc/bench.json"])
def test_unwritable_out_is_one_error_before_measuring(out, tmp_path, capsys):
    out = str(tmp_path) if out == "DIR" else out
    assert cli.main(["--out", out]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith("error: ") and captured.err.count("\n") == 1


def test_missing_sb3_is_one_error_unless_no_section_needs_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "find_spec", lambda name: None)
    assert cli.main(["--out", str(tmp_path / "bench.json")]) == 1
    assert "pip install -e '.[dev]'" in capsys.readouterr().err
    assert cli.check_ready(tmp_path / "bench.json", ["env", "team"]) is None


def test_the_game_batch_rates_measure_both_ways_the_loop_can_step_its_games():
    rows = list(game_batches.measure([2, 6], ["deliberative"], repeats=1, seconds=0.01))
    assert [(row.mode, row.replicas) for row in rows] == [("deliberative", 2), ("deliberative", 6)]
    assert all(0 < row.looped < float("inf") and 0 < row.batched < float("inf") for row in rows)


FAKE_TRAIN = """import json, os, sys
with open(os.path.join(os.path.dirname(__file__), "calls.jsonl"), "a") as calls:
    call = {"argv": sys.argv[1:], "pythonpath": os.environ.get("PYTHONPATH"), "cwd": os.getcwd()}
    calls.write(json.dumps(call) + "\\n")
"""


def fake_checkout(tmp_path):
    (tmp_path / "dqn_transfer").mkdir()
    (tmp_path / "train.py").write_text(FAKE_TRAIN)
    return tmp_path


def test_a_baseline_checkout_runs_its_own_train_py_twice_on_the_study_command_line(tmp_path):
    checkout = fake_checkout(tmp_path)
    out = tabular_batches.measure_marginal(checkout, replicas=3, mode="deliberative", short=10, long=30, seed=5)
    calls = [json.loads(line) for line in (checkout / "calls.jsonl").read_text().splitlines()]
    assert [call["pythonpath"] for call in calls] == [str(checkout)] * 2  # its own package, not ours
    assert [call["cwd"] for call in calls] == [str(checkout)] * 2
    for call, steps in zip(calls, (10, 30)):
        argv = call["argv"]
        assert {"agent=sarsa", "env=study/m4", "mode=deliberative", "replicas.seeds=3", "seed=5"} <= set(argv)
        assert f"total_steps={steps}" in argv and f"checkpoint_every={steps}" in argv
    assert out["seconds_per_1k_steps"] == pytest.approx((out["long_seconds"] - out["short_seconds"]) * 1000 / 20)


def test_our_side_of_the_tabular_section_is_a_command_line_the_cli_accepts():
    command = tabular_batches.tabular_command(None, Path("/tmp/x"), 60, 4, "cooperative", 0)
    assert command[1:3] == ["-m", "dqn_transfer.cli.train"]
    check_overrides(command[3:])  # every override names a key of the schema


def test_the_tabular_section_pairs_each_repeat_and_tables_it(tmp_path, monkeypatch):
    seconds = {None: iter([2.0, 3.0, 1.0, 1.5]), "baseline": iter([10.0, 9.0, 8.0, 9.0])}

    def fake_marginal(checkout, replicas, mode, short, long, seed):
        value = next(seconds[None if checkout is None else "baseline"])
        return {
            "seconds_per_1k_steps": value,
            "cpu_seconds_per_1k_steps": value / 2,
            "agent_steps_per_s": 1000 * replicas * 4 / value,
            "max_rss_mb": 100.0,
        }

    monkeypatch.setattr(suite, "measure_marginal", fake_marginal)
    sizes = dataclasses.replace(TINY_SIZES, tabular_counts=(1, 2), tabular_modes=("cooperative",))
    section = suite.tabular_section(sizes, seed=0, repeats=2, baseline=fake_checkout(tmp_path), progress=print)
    # rows in order R = 1, 2; per row, repeat 0 then 1; ratios baseline / ours by repeat, then the median
    assert [row["speedup"] for row in section["rows"]] == [
        statistics.median([10 / 2, 9 / 3]),
        statistics.median([8 / 1, 9 / 1.5]),
    ]
    assert [row["ours"]["seconds_per_1k_steps"] for row in section["rows"]] == [2.5, 1.25]
    document = {"machine": suite.machine_info([1], None), "tabular": section}
    table = "\n".join(tables._tabular_table(document))
    assert "## 7." in table and "| cooperative | 2 | 1.25 |" in table and "7.00x" in table


def test_a_bad_baseline_is_one_error_before_measuring(tmp_path, capsys):
    out = str(tmp_path / "bench.json")
    assert cli.main(["--only", "tabular", "--baseline", str(tmp_path), "--out", out]) == 1
    assert "not a checkout of dqn_transfer" in capsys.readouterr().err
    assert cli.main(["--only", "env", "--baseline", str(fake_checkout(tmp_path)), "--out", out]) == 1
    assert "--only tabular" in capsys.readouterr().err
