"""`dqn-transfer-export marl-eval`: runs and the study's raw data in marl-eval's JSON, read back by
id-marl-eval's own processing, which gives the same IQM as this project's statistics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from rliable import metrics as rliable_metrics

from dqn_transfer.analysis.marl_eval import (
    ABSOLUTE,
    EvaluatedRun,
    algorithm_name,
    layout_problems,
    marl_eval_tree,
    task_name,
)
from dqn_transfer.analysis.stats import iqm
from dqn_transfer.analysis.transfer_metrics import asymptotic_performance
from dqn_transfer.cli.export import main
from dqn_transfer.config import AgentConfig, ReplicasConfig, TrainConfig
from dqn_transfer.enums import Algorithm, Logger
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.experiments.claims import exchange_condition
from dqn_transfer.experiments.export import agent_returns
from dqn_transfer.experiments.pipeline import sweep_jobs
from dqn_transfer.experiments.raw_data import RunData, read_data
from dqn_transfer.experiments.scoring import FINAL_TAIL, by_map, final_score, learner, mode
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "results" / "v1" / "data"


def marl_eval_matrices(path: Path, environment: str) -> tuple[dict, list[str]]:
    """marl-eval's own reading of an export: ``({metric: {algorithm: [runs, tasks]}}, tasks)``."""
    processing = pytest.importorskip("marl_eval.utils.data_processing_utils")
    raw = json.loads(path.read_text())
    processed = processing.data_process_pipeline(raw_data=raw, metrics_to_normalize=[])
    assert "extra" in processed, "marl-eval's pipeline refused the export"
    matrices, curves = processing.create_matrices_for_rliable(processed, environment, [])
    return matrices, list(processed[environment])


def test_the_study_data_give_marl_eval_the_study_s_iqm(tmp_path, capsys):
    out = tmp_path / "hypothesis.json"
    assert main(["marl-eval", "--data", str(DATA / "hypothesis.jsonl"), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    matrices, tasks = marl_eval_matrices(out, "treasurehunt_hypothesis")
    runs = read_data(DATA / "hypothesis.jsonl")
    compared = 0
    for algorithm in ("double_dqn", "sarsa"):
        for exchange in ("none", "best", "shared_replay"):
            name = algorithm + ("" if exchange == "none" else f"+exchange_{exchange}")
            for team_mode in ("cooperative", "deliberative"):
                members = [
                    r for r in runs if (learner(r), mode(r), exchange_condition(r)) == (algorithm, team_mode, exchange)
                ]
                ours = iqm(by_map(members, final_score), np.random.default_rng(0)).mean  # as claims.hypothesis
                columns = [i for i, task in enumerate(tasks) if task.startswith(team_mode)]
                matrix = matrices["mean_score"][name][:, columns]  # [seeds, maps of this mode]
                assert matrix.shape == (2, 5)
                theirs = float(rliable_metrics.aggregate_iqm(matrix))  # marl-eval's aggregate_scores' IQM
                assert theirs == pytest.approx(ours, rel=1e-12, abs=1e-12), (name, team_mode)
                compared += 1
    assert compared == 12


def write_run_dir(run: RunData, directory: Path) -> None:
    """A run directory as the trainer leaves it, as far as the readers go: its config and evaluations."""
    (directory / ".hydra").mkdir(parents=True)
    (directory / ".hydra" / "config.yaml").write_text(yaml.safe_dump(run.config))
    lines = [{"step": s, **{m: v[i] for m, v in run.metrics.items()}} for i, s in enumerate(run.steps)]
    (directory / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))


def test_run_directories_give_marl_eval_the_same_iqm_as_ours(tmp_path):
    runs = read_data(DATA / "hypothesis_shared.jsonl")
    for run in runs:
        write_run_dir(run, tmp_path / "sweep" / run.name)
    out = tmp_path / "runs.json"
    assert main(["marl-eval", str(tmp_path / "sweep"), "--out", str(out)]) == 0
    tree = json.loads(out.read_text())
    entry = tree["treasurehunt"]["cooperative-4agents-8x8-map0"]["double_dqn+shared"]["seed_0"]
    assert entry["step_0"]["step_count"] == 0 and set(entry) == {f"step_{i}" for i in range(17)} | {ABSOLUTE}
    assert {"team_return", "success_rate", "trap_rate", "score"} <= set(entry[ABSOLUTE])
    assert not any(key.startswith("agent_") for key in entry[ABSOLUTE])  # records without agent_returns
    matrices, tasks = marl_eval_matrices(out, "treasurehunt")
    for metric in ("score", "team_return", "success_rate"):
        theirs = float(rliable_metrics.aggregate_iqm(matrices[f"mean_{metric}"]["double_dqn+shared"]))
        finals = [final_score(r) if metric == "score" else _final(r, metric) for r in runs]
        assert theirs == pytest.approx(iqm(np.asarray(finals), np.random.default_rng(0)).mean, rel=1e-12), metric


@pytest.mark.filterwarnings("ignore:a layout fixes the map")
def test_each_agent_s_return_reaches_marl_eval_as_metrics_jsonl_has_it(tmp_path):
    """Two replicas trained for real: each agent's return at each evaluation is the later record's of
    its step in ``metrics.jsonl`` (read here with json alone), as ``agent_<i>_return`` beside the team's
    metrics; marl-eval's own processing reads them, and its rliable matrices hold the final means."""
    config = TrainConfig(
        env=EnvConfig(layout="0...T\n.#...\n...#.\nX....\n1..T.\n"),
        agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.1),
        seed=4,
        total_steps=500,
        eval_every=100,
        eval_episodes=2,
        checkpoint_every=500,
        progress=False,
        logger=[Logger.csv],
        replicas=ReplicasConfig(seeds=2),
    )
    batch = tmp_path / "batch"
    train(plan_run(config), batch)
    names = json.loads((batch / "replicas.json").read_text())["replicas"]
    # a resumed run evaluates a step again: the later line counts (here the last step's, other returns)
    with (batch / names[0] / "metrics.jsonl").open("r+") as stream:
        last = json.loads(stream.read().splitlines()[-1])
        stream.write(json.dumps({**last, "agent_returns": [-1000.0, 1000.0]}) + "\n")
    out = tmp_path / "runs.json"
    assert main(["marl-eval", str(batch), "--out", str(out)]) == 0
    raw = json.loads(out.read_text())
    (task,) = raw["treasurehunt"]
    processing = pytest.importorskip("marl_eval.utils.data_processing_utils")
    processed = processing.data_process_pipeline(raw_data=json.loads(out.read_text()), metrics_to_normalize=[])
    assert "extra" in processed, "marl-eval's pipeline refused the export"
    finals = {0: [], 1: []}
    for name in names:
        lines = [json.loads(line) for line in (batch / name / "metrics.jsonl").read_text().splitlines()]
        later = {line["step"]: line["agent_returns"] for line in lines}  # the later line of a step wins
        seed = yaml.safe_load((batch / name / ".hydra" / "config.yaml").read_text())["seed"]
        entry = raw["treasurehunt"][task]["qlearning"][f"seed_{seed}"]
        read = processed["treasurehunt"][task]["qlearning"][f"seed_{seed}"]
        assert (
            [entry[f"step_{i}"]["step_count"] for i in range(len(later))]
            == sorted(later)
            == [0, 100, 200, 300, 400, 500]
        )
        for agent in (0, 1):
            values = [later[step][agent] for step in sorted(later)]
            for i, value in enumerate(values):
                assert entry[f"step_{i}"][f"agent_{agent}_return"] == [value]
                assert read[f"step_{i}"][f"mean_agent_{agent}_return"] == value
            tail = values[-math.ceil(FINAL_TAIL * len(values)) :]  # the last 20% of the evaluations
            assert entry[ABSOLUTE][f"agent_{agent}_return"] == [pytest.approx(sum(tail) / len(tail), rel=1e-12)]
            finals[agent].append(sum(tail) / len(tail))
        if name == names[0]:
            assert entry[f"step_{len(later) - 1}"]["agent_0_return"] == [-1000.0]
    matrices, _ = processing.create_matrices_for_rliable(processed, "treasurehunt", [])
    for agent in (0, 1):
        matrix = matrices[f"mean_agent_{agent}_return"]["qlearning"]  # [seeds, tasks]
        assert sorted(matrix[:, 0]) == pytest.approx(sorted(finals[agent]), rel=1e-12)


def test_agent_returns_are_left_out_unless_every_record_has_them(tmp_path):
    """Records written before ``agent_returns`` was kept (the study's runs), or a run resumed across that
    change: no per-agent metric rather than a partial one."""
    lines = [
        {"step": 0, "team_return": 1.0},
        {"step": 100, "team_return": 2.0, "agent_returns": [1.5, 0.5]},
        {"step": 200, "team_return": 3.0, "agent_returns": [2.0, 1.0]},
    ]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    assert agent_returns(tmp_path, [0, 100, 200]) == {}
    assert agent_returns(tmp_path, [100, 200]) == {"agent_0_return": (1.5, 2.0), "agent_1_return": (0.5, 1.0)}
    assert agent_returns(tmp_path, []) == {}


def _final(run: RunData, metric: str) -> float:
    return asymptotic_performance(run.curve(metric), FINAL_TAIL)


def _run(name: str, seed: int, steps=(0, 100), **config) -> EvaluatedRun:
    base = {
        "seed": seed,
        "env": {"mode": "competitive", "num_agents": 2, "size": 6, "map_seed": 0},
        "agent": {"algorithm": "sarsa", "lr": 0.1},
        "transfer": {"enabled": False, "exchange": "none"},
    }
    for key, value in config.items():
        base[key] = {**base[key], **value}
    return EvaluatedRun(name, base, steps, {"team_return": [float(s) for s in steps]})


def test_runs_that_would_share_a_name_are_told_apart_by_their_config():
    tree = marl_eval_tree([_run("a", 0), _run("b", 0, agent={"lr": 0.5}), _run("c", 1)], 0.5)
    algorithms = sorted(tree["treasurehunt"]["competitive-2agents-6x6-map0"])
    assert algorithms == ["sarsa;agent.lr=0.1", "sarsa;agent.lr=0.5"]
    assert not any("," in a for a in algorithms)
    assert layout_problems(tree) == ["treasurehunt: the tasks' algorithms do not all have the same seeds"]


def test_the_same_run_twice_is_an_error():
    with pytest.raises(ValueError, match="same task, algorithm and seed"):
        marl_eval_tree([_run("a", 0), _run("b", 0)], 0.5)


@pytest.mark.parametrize("case", ["no runs", "not a run dir", "existing out", "bad data"])
def test_bad_input_is_one_error_line_and_nothing_written(tmp_path, capsys, case):
    out = tmp_path / "out.json"
    args = {
        "no runs": ["marl-eval", "--out", str(out)],
        "not a run dir": ["marl-eval", str(tmp_path), "--out", str(out)],
        "existing out": ["marl-eval", "--data", str(DATA / "claim1.jsonl"), "--out", str(out)],
        "bad data": ["marl-eval", "--data", str(tmp_path / "missing.jsonl"), "--out", str(out)],
    }[case]
    if case == "existing out":
        out.write_text("keep")
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    assert (out.read_text() == "keep") if case == "existing out" else not out.exists()


def test_the_second_editions_conditions_have_names_of_their_own():
    hypothesis = {job.values["method"]: job.config for job in sweep_jobs("v2/hypothesis")}
    assert algorithm_name(hypothesis["double_dqn_shared_id"]) == "double_dqn+shared+id"
    assert algorithm_name(hypothesis["double_dqn_vdn"]) == "double_dqn+vdn"
    assert algorithm_name(hypothesis["sarsa_advice"]) == "sarsa+exchange_advice"
    transfer = {
        job.values["condition"]: job.config
        for job in sweep_jobs("v2/transfer") + sweep_jobs("v2/transfer_aware")
        if job.values["method"] == "sarsa_none"
    }
    assert algorithm_name(transfer["same_map"]) == "sarsa+transfer"
    assert algorithm_name(transfer["same_map_own"]) == "sarsa+transfer_own"
    assert algorithm_name(transfer["same_map_own_aware"]) == "sarsa+transfer_own+chest_aware"
    (lbf, *_) = [job.config for job in sweep_jobs("v2/lbf_hypothesis")]
    assert task_name(lbf) == "lbf-map0"  # another game: its module and instance, not the treasure map's keys


def test_each_experiment_of_the_second_edition_is_an_environment_named_after_its_game(tmp_path):
    # The replication on Level-Based Foraging is not a treasure hunt: its environment says so.
    v2 = ROOT / "results" / "v2" / "data"
    out = tmp_path / "v2.json"
    data = [str(v2 / "claim1.jsonl"), str(v2 / "lbf_hypothesis.jsonl")]
    assert main(["marl-eval", "--data", *data, "--out", str(out)]) == 0
    tree = json.loads(out.read_text())
    assert sorted(tree) == ["lbf_lbf_hypothesis", "treasurehunt_claim1"]
    assert sorted(tree["lbf_lbf_hypothesis"]) == sorted(f"lbf-map{m}" for m in range(30))
    assert sorted(tree["lbf_lbf_hypothesis"]["lbf-map0"]["sarsa"]) == ["seed_0", "seed_1", "seed_2"]
