"""The study's pipeline on its editions (conf/edition/): comparison groups from the sweeps, the registered budget
rule on pilot runs (budgets worked out by hand), the pilot and full stages end to end on the quick profile, and
the command's refusals."""

import json
import shutil
from pathlib import Path

import pytest

from dqn_transfer.cli import study as cli
from dqn_transfer.experiments.edition import load_edition
from dqn_transfer.experiments.pipeline import (
    group_overrides,
    pilot_budgets,
    read_budgets,
    sweep_groups,
    sweep_jobs,
    write_budgets,
)
from dqn_transfer.experiments.raw_data import DataError, RunData, read_data, write_data
from dqn_transfer.experiments.sweeps import ReproduceError

V2 = load_edition("v2")

SARSA = "sarsa_none,sarsa_best,sarsa_shared_replay,sarsa_confidence,sarsa_advice"
DQN = (
    "double_dqn_none,double_dqn_best,double_dqn_shared_replay,double_dqn_experience,double_dqn_shared_id,double_dqn_vdn"
)


def test_the_hypothesis_runs_one_multirun_per_learner_and_mode():
    groups = {key: group_overrides(jobs) for key, jobs in sweep_groups(V2, "hypothesis").items()}
    assert groups == {
        ("sarsa", "cooperative"): [f"method={SARSA}", "mode=cooperative"],
        ("sarsa", "deliberative"): [f"method={SARSA}", "mode=deliberative"],
        ("double_dqn", "cooperative"): [f"method={DQN}", "mode=cooperative"],
        ("double_dqn", "deliberative"): [f"method={DQN}", "mode=deliberative"],
    }


def _pilot_run(job_config: dict, job: int, map_seed: int, values: list[float]) -> RunData:
    config = json.loads(json.dumps(job_config))
    config["env"]["map_seed"] = map_seed
    steps = tuple(range(0, 32_001, 500))
    return RunData("claim1", f"{job}/seed_0-map_{map_seed}", config, steps, {"team_return": tuple(values)}, 0, None)


def test_the_budget_rule_on_claim1s_pilot(tmp_path):
    # Claim 1's maps have no optimum: the rule reads team return in chests (/100). Competitive runs gain
    # 0.05 return per step up to step 4,000, then stay flat: cut at T, the last half of the evaluations is flat
    # from T = 7,500 (8 points, 4,000..7,500) and holds a lower point before it, so S = 7,500 and the budget
    # 1.5 x 7,500 = 11,250, rounded up to 12,000. Cooperative runs are flat from the start: S is the first step
    # with 4 evaluations, 1,500, and the budget 2,250 -> 3,000. The group runs at the larger, 12,000.
    jobs = sweep_jobs("v2/claim1")
    assert [job.values for job in jobs] == [{"mode": "competitive"}, {"mode": "cooperative"}]
    rising = [0.05 * min(step, 4000) for step in range(0, 32_001, 500)]
    runs = [_pilot_run(jobs[0].config, 0, 2000 + m, rising) for m in range(3)]
    runs += [_pilot_run(jobs[1].config, 1, 2000 + m, [20.0] * len(rising)) for m in range(3)]
    write_data(tmp_path / "pilot" / "claim1.jsonl", runs[::-1])  # any order: runs find their job by config
    (group,) = pilot_budgets(V2, tmp_path / "pilot", ["claim1"], V2.profiles["full"])
    assert [(c.values["mode"], c.runs, c.budget.converged_step, c.budget.budget) for c in group.cells] == [
        ("competitive", 3, 7_500, 12_000),
        ("cooperative", 3, 1_500, 3_000),
    ]
    assert (group.comparison, group.key, group.budget) == ("claim1", (), 12_000)
    write_budgets(tmp_path, [group], V2.rule)
    assert read_budgets(tmp_path / "budgets.json") == {("claim1", ()): 12_000}
    # margin: the flat windows after 7,500 have slope 0, 0.01 below the threshold; the ones before are steep
    table = (tmp_path / "budgets.md").read_text()
    assert "| claim1 | all | mode=competitive | 3 | 7,500 | 0.0100 | 12,000 | 12,000 |" in table


def test_a_pilot_run_of_no_job_of_the_sweep_is_refused(tmp_path):
    jobs = sweep_jobs("v2/claim1")
    stray = json.loads(json.dumps(jobs[0].config))
    stray["env"]["mode"] = "deliberative"
    write_data(tmp_path / "claim1.jsonl", [_pilot_run(stray, 0, 2000, [0.0] * 65)])
    with pytest.raises(DataError, match="matches 0 jobs"):
        pilot_budgets(V2, tmp_path, ["claim1"], V2.profiles["full"])


def test_the_full_stage_refuses_a_group_without_a_budget(tmp_path, capsys):
    (tmp_path / "budgets.json").write_text(json.dumps({"groups": []}))
    assert cli.main(["full", "--edition", "v2", "--out", str(tmp_path), "--only", "claim1", "--launcher", "basic"]) == 1
    assert "has no budget for claim1 all" in capsys.readouterr().err
    assert cli.main(["pilot", "--edition", "v2", "--out", str(tmp_path), "--only", "claim9"]) == 1
    assert "unknown experiment(s) claim9" in capsys.readouterr().err
    with pytest.raises(ReproduceError, match="not a budgets file"):
        (tmp_path / "bad.json").write_text("[]")
        read_budgets(tmp_path / "bad.json")


def test_the_quick_pilot_and_full_stages_run_end_to_end(tmp_path):
    # Real Hydra multiruns (basic launcher): the pilot on the pilot maps, budgets, then the full runs at them.
    common = [
        "--edition",
        "v2",
        "--out",
        str(tmp_path),
        "--profile",
        "quick",
        "--only",
        "claim1",
        "--launcher",
        "basic",
    ]
    assert cli.main(["pilot", *common]) == 0
    pilot = read_data(tmp_path / "pilot" / "data" / "claim1.jsonl")
    assert sorted(r.unit for r in pilot) == [(2000, 0), (2000, 0), (2001, 0), (2001, 0)]  # 2 modes x 2 pilot maps
    budget = read_budgets(tmp_path / "budgets.json")[("claim1", ())]
    assert 1_000 <= budget <= 2_000  # the quick profile's cap
    assert cli.main(["full", *common]) == 0
    runs = read_data(tmp_path / "data" / "claim1.jsonl")
    assert sorted(r.unit for r in runs) == [(0, 0), (0, 0), (1, 0), (1, 0)]  # evaluation maps 0, 1
    assert {r.steps[-1] for r in runs} == {budget} and {r.name.split("/")[0] for r in runs} == {"all"}


def test_the_committed_budgets_come_from_the_committed_pilot_data_and_one_experiments_pilot_keeps_the_rest(tmp_path):
    # `pilot --report-only --only claim1` recomputes the budgets from every experiment's pilot data in OUT, not
    # from claim 1's alone: the other experiments' budgets stay, and all equal the committed ones.
    results = Path(__file__).resolve().parents[1] / "results" / "v2"
    shutil.copytree(results / "pilot" / "data", tmp_path / "pilot" / "data")
    assert cli.main(["pilot", "--edition", "v2", "--out", str(tmp_path), "--report-only", "--only", "claim1"]) == 0
    assert (tmp_path / "budgets.md").read_text() == (results / "budgets.md").read_text()
    assert json.loads((tmp_path / "budgets.json").read_text()) == json.loads((results / "budgets.json").read_text())


def test_an_edition_is_refused_a_stage_it_does_not_have_and_an_unknown_edition_in_one_line(tmp_path, capsys):
    assert cli.main(["pilot", "--edition", "v1", "--out", str(tmp_path)]) == 1
    assert capsys.readouterr().err == "error: edition v1 has no pilot stage (its stages: full, report)\n"
    assert cli.main(["full", "--edition", "v9", "--out", str(tmp_path)]) == 1
    assert capsys.readouterr().err == "error: no edition 'v9' (choose from v1, v2, v3)\n"
    assert not any(tmp_path.iterdir())  # refused before anything is written


def test_each_edition_file_reads_as_its_design():
    # The first edition: its six experiment files as they are, no pilot; the second: six experiments of
    # conf/experiment/v2/ through every stage, at the registered rule (results/v2/VERDICT_RULES.md).
    v1 = load_edition("v1")
    assert (v1.experiment("claim2"), v1.stages, v1.rule, v1.analysis) == ("claim2", ("full", "report"), None, "paired")
    assert v1.profiles["quick"].run_overrides("claim1") == (
        "total_steps=600",
        "eval_every=100",
        "replicas.seeds=1",
        "replicas.maps=3",
    )
    assert v1.profiles["quick"].description.endswith("is NOT evidence for or against any claim.")
    assert V2.experiment("transfer_aware") == "v2/transfer_aware" and V2.stages == ("tune", "pilot", "full", "report")
    assert (V2.rule.threshold, V2.rule.safety, V2.rule.cap, V2.rule.fraction) == (0.01, 1.5, 32_000, 0.5)
    assert V2.comparisons["transfer_aware"].name == "transfer"
    assert V2.comparisons["claim2"].key({"env": {"num_agents": 3, "contention": "shared"}}) == (3, "shared")
