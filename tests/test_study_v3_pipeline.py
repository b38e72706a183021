"""The third edition's pipeline (conf/edition/v3.yaml): its tuning runs each cell's own config on the tuning
maps with the same trials per searched key, each condition of a cell runs at its tuned values in chunks of
maps, the power rule sets the maps, and the report gives the registered outcomes from the data alone."""

import dataclasses
import json
import math
from pathlib import Path

import pytest
import scipy.stats
import yaml
from conftest import read_metrics, without_timing

from dqn_transfer.cli import report as report_cli
from dqn_transfer.cli import study
from dqn_transfer.config import to_plain
from dqn_transfer.experiments import cell_runs, sweeps, tuning
from dqn_transfer.experiments.cell_runs import (
    CellJob,
    CellMaps,
    ComparisonPower,
    cell_jobs,
    chunk_multirun,
    map_chunks,
    maps_per_cell,
    write_maps,
)
from dqn_transfer.experiments.edition import load_edition
from dqn_transfer.experiments.equivalence_report import write_report
from dqn_transfer.experiments.pipeline import record_stage
from dqn_transfer.experiments.raw_data import RunData, write_data, write_manifest
from dqn_transfer.experiments.sweeps import composed, swept_values
from dqn_transfer.storage.run_dir import flatten

V3 = load_edition("v3")
TUNING = {cell.name: cell for cell in V3.tuning}
# What a tuning trial sets apart from the study's runs: its maps, its seed count, and what it maximises.
TRIAL_ONLY = {"env.map_seed", "replicas.maps", "replicas.seeds", "objective"}
CELL_OF_TUNING = {
    "treasure": {"sarsa": ("sarsa", ["env=study/m4_10"]), "double_dqn": ("double_dqn", [])},
    "lbf": {"sarsa": ("lbf", [])},
}


def _flat(config) -> dict:
    return flatten(to_plain(config), lambda leaf: leaf)


@pytest.mark.parametrize("cell, search", [(c.name, s) for c in V3.tuning for s in c.searches])
def test_a_tuning_trial_runs_the_cells_own_config_on_the_tuning_maps(cell, search):
    experiment, where = CELL_OF_TUNING[cell][tuning.search_named(search).learner]
    trial = _flat(composed(f"tune/{search}", list(TUNING[cell].overrides)))
    run = _flat(composed(f"v3/{experiment}", [f"method={search}", *where]))
    differing = {key for key in trial.keys() | run.keys() if trial.get(key) != run.get(key)}
    assert differing <= TRIAL_ONLY, {key: (trial.get(key), run.get(key)) for key in differing - TRIAL_ONLY}
    assert trial["env.map_seed"] == 1000 and trial["replicas.maps"] == 5 and trial["replicas.seeds"] == 1


def test_every_search_gets_eight_trials_per_searched_key(monkeypatch, tmp_path):
    ran = []
    monkeypatch.setattr(tuning, "run_multirun", lambda multirun, *args: ran.append(multirun))
    searches = [tuning.search_named(n) for n in ("sarsa_none", "sarsa_advice", "double_dqn_experience")]
    multiruns = tuning.search_multiruns(searches, TUNING["treasure"].overrides, tmp_path, V3.trials_per_dimension)
    tuning.run_searches([(m, tmp_path) for m in multiruns], 1)
    # The searched keys, counted by hand in conf/experiment/tune/: lr; lr and three advice keys; lr and lambda.
    assert {m.label: m.jobs for m in ran} == {"sarsa_none": 8, "sarsa_advice": 32, "double_dqn_experience": 16}
    # The longest first, trials x a trial's seconds: 16 x 20 s, 32 x 6 s, 8 x 6 s.
    assert [m.label for m in ran] == ["double_dqn_experience", "sarsa_advice", "sarsa_none"]


def test_every_tuning_cells_searches_share_one_pool(monkeypatch, tmp_path):
    # One pool for the treasure hunt's and LBF's searches: a core freed by one cell's last search takes the
    # other's next, and the longest of both start first; then each cell's trials are analysed in its directory.
    pooled, analysed = [], []
    monkeypatch.setattr(tuning, "run_searches", lambda planned, parallel: pooled.extend(planned))
    monkeypatch.setattr(tuning, "collect_trials", lambda searches, out: [])
    monkeypatch.setattr(tuning, "write_trials", lambda path, trials: None)
    monkeypatch.setattr(tuning, "analyse", lambda out: analysed.append(out) or [out / "tuned.yaml"])
    cells = [
        ([tuning.search_named("double_dqn_none")], TUNING["treasure"].overrides, tmp_path / "treasure"),
        ([tuning.search_named("sarsa_none")], TUNING["lbf"].overrides, tmp_path / "lbf"),
    ]
    written = tuning.tune(cells, 2, V3.trials_per_dimension)
    assert [(m.label, out.name) for m, out in pooled] == [("double_dqn_none", "treasure"), ("sarsa_none", "lbf")]
    assert analysed == [tmp_path / "treasure", tmp_path / "lbf"]
    assert written == [tmp_path / "treasure" / "tuned.yaml", tmp_path / "lbf" / "tuned.yaml"]


def _tuned(tmp_path: Path) -> Path:
    values = {
        "sarsa": {
            "none": {"agent.lr": 0.25},
            "shared_replay": {"agent.lr": 0.5, "transfer.exchange_every": 7},
            "best": {"agent.lr": 0.125, "transfer.exchange_every": 3, "transfer.exchange_tau": 0.75},
        }
    }
    path = tmp_path / "tuning" / "treasure" / "tuned.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(yaml.safe_dump(values))
    return tmp_path


def test_each_condition_runs_at_its_tuned_values_and_a_control_at_those_of_what_it_controls(tmp_path):
    out = _tuned(tmp_path)
    s6 = next(cell for cell in V3.cells if cell.name == "S6")
    jobs = cell_jobs(V3, s6, swept_values("v3/sarsa"))
    assert [job.condition for job in jobs] == ["none", "best", "shared_replay", "confidence", "advice", "sham", "warm"]
    assert {job.values["env"] for job in jobs} == {"study/m6"}
    by_condition = {job.condition: job for job in jobs}
    sham = chunk_multirun(V3, by_condition["sham"], out, 10, 30, "full", "full")
    assert sham.overrides == (
        "method=sarsa_sham",
        "env=study/m6",
        "agent.lr=0.5",
        "transfer.exchange_every=7",
        "env.map_seed=10",
        "replicas.maps=30",
    )
    assert sham.sweep_dir == out / "runs" / "sarsa" / "S6" / "sham" / "maps-10-39" and sham.jobs == 1
    warm = chunk_multirun(V3, by_condition["warm"], out, 0, 10, "full", "pilot")
    assert "agent.lr=0.25" in warm.overrides and warm.stamp["stage"] == "pilot"
    config = composed("v3/sarsa", list(sham.overrides))  # what the run gets: the tuned values, the maps
    assert (config.agent.lr, config.transfer.exchange_every, config.transfer.exchange.value) == (0.5, 7, "sham")
    assert (config.env.num_agents, config.env.map_seed, config.replicas.maps, config.replicas.seeds) == (6, 10, 30, 3)


def test_a_condition_without_tuned_values_is_refused_in_one_line(tmp_path):
    out = _tuned(tmp_path)
    s4 = next(cell for cell in V3.cells if cell.name == "S4")
    with pytest.raises(cell_runs.ReproduceError, match="no tuned values of sarsa x advice"):
        chunk_multirun(V3, CellJob(s4, {"method": "sarsa_advice", "env": "study/m4_10"}), out, 0, 10, "full", "pilot")
    with pytest.raises(cell_runs.ReproduceError, match="run the tune stage first"):
        chunk_multirun(V3, CellJob(s4, {"method": "sarsa_none"}), tmp_path / "empty", 0, 10, "full", "pilot")


def _tuned_double_dqn(tmp_path: Path) -> Path:
    path = tmp_path / "tuning" / "treasure" / "tuned.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(yaml.safe_dump({"double_dqn": {"none": {"agent.lr": 0.001}, "shared_replay": {"agent.lr": 0.002}}}))
    return tmp_path


def test_a_cells_maps_are_split_into_the_fewest_equal_chunks_that_fit_the_memory_bound(tmp_path):
    out = _tuned_double_dqn(tmp_path)
    d4 = next(cell for cell in V3.cells if cell.name == "D4")
    none, shared = (CellJob(d4, {"method": f"double_dqn_{c}"}) for c in ("none", "shared_replay"))
    # By hand, for a map of D4 (3 seeds x 4 agents; observations one-hot over 10x10 cells + 4 chests: 104 wide;
    # a replay row 2 x 104 + 3 float32; networks 104-64-64-4, 11,140 parameters x 5 copies x 4 bytes):
    # shared replay fills each agent's 50,000 rows: 3 x 4 x (50,000 x 211 x 4 + 222,800) = 509 MB a map, so
    # 3 maps fit in 1.6 GB and 4 do not; without it 16,000 rows: 164.7 MB a map, 1.65 GB for 10 maps.
    bounded = dataclasses.replace(V3, chunk_gigabytes=1.6)
    assert map_chunks(bounded, shared, out, 10, 10, "full") == [(10, 3), (13, 3), (16, 2), (18, 2)]
    assert map_chunks(bounded, none, out, 10, 10, "full") == [(10, 5), (15, 5)]
    assert map_chunks(dataclasses.replace(V3, chunk_gigabytes=None), shared, out, 10, 10, "full") == [(10, 10)]
    with pytest.raises(cell_runs.ReproduceError, match=r"one map's replicas need about 0.51 GB"):
        map_chunks(dataclasses.replace(V3, chunk_gigabytes=0.4), shared, out, 10, 10, "full")


def test_a_chunks_runs_are_those_of_one_batch_and_a_finished_chunk_keeps_no_checkpoints(tmp_path):
    """Maps 0-1 in one multirun and map 1 alone train the same replica bit for bit; once finished, a
    cell's multirun has deleted its checkpoints (a Double DQN run's hold its replay) and is reused."""
    out = _tuned_double_dqn(tmp_path)
    job = CellJob(next(cell for cell in V3.cells if cell.name == "D4"), {"method": "double_dqn_shared_replay"})
    short = ("replicas.seeds=1", "total_steps=240", "eval_every=120", "agent.learning_starts=60", "eval_episodes=1")

    def run(first: int, count: int) -> tuple[Path, float]:
        multirun = chunk_multirun(V3, job, out, first, count, "full", "full")
        multirun = dataclasses.replace(multirun, overrides=(*multirun.overrides, *short))
        return multirun.sweep_dir / "0", sweeps.run_multirun(multirun, out, "basic", 1, poll_seconds=0.2)

    (both, _), (alone, _) = run(0, 2), run(1, 1)
    assert without_timing(read_metrics(both / "seed_0-map_1")) == without_timing(read_metrics(alone))
    for run_dir in (both / "seed_0-map_0", both / "seed_0-map_1", alone):
        assert (run_dir / "metrics.jsonl").is_file() and not (run_dir / "checkpoints").exists()
    assert run(0, 2) == (both, 0.0)  # finished: reused as it is, without its checkpoints


# ------------------------------------------------------------------------------------------- runs made by hand

STEPS = tuple(range(0, 16_001, 500))
ENV = {"size": 6, "num_treasures": 2, "num_traps": 1, "num_agents": 2, "complexity": 0.1, "mode": "cooperative"}
OPTIMUM = 200.0


def _run(cell: str, condition: str, map_seed: int, seed: int, score: float) -> RunData:
    """A run whose every evaluation returns ``score`` x the map's optimum."""
    config = {
        "seed": seed,
        "total_steps": 16_000,
        "agent": {"algorithm": "sarsa"},
        "env": {**ENV, "map_seed": map_seed},
    }
    name = f"{cell}/{condition}/maps-0-9/0/replica-{map_seed * 3 + seed}"
    return RunData("sarsa", name, config, STEPS, {"team_return": (score * OPTIMUM,) * len(STEPS)}, 0, OPTIMUM)


def _cell(cell: str, shifts: dict[str, float], maps: int = 4, seeds: int = 3, spread: float = 0.0) -> list[RunData]:
    """Every condition's runs: ``none`` scores 0.3 + 0.02 map - 0.01 seed; a condition ``shift`` more; ``spread``
    adds +-spread on alternate (map, seed) units to every condition but ``none``."""
    runs = []
    for condition, shift in {"none": 0.0, **shifts}.items():
        for m in range(maps):
            for s in range(seeds):
                noise = 0.0 if condition == "none" else spread * (1 if (m + s) % 2 else -1)
                runs.append(_run(cell, condition, m, s, 0.3 + 0.02 * m - 0.01 * s + shift + noise))
    return runs


def _t_power(sigma_map: float, sigma_run: float, maps: int) -> float:
    """The two-sided t-test's power at 0.03 over ``maps`` map means of 3 seeds at Holm's 0.05 / 2."""
    shift = 0.03 / math.sqrt((sigma_map**2 + sigma_run**2 / 3) / maps)
    critical = scipy.stats.t.ppf(1 - 0.025 / 2, maps - 1)
    return scipy.stats.nct.sf(critical, maps - 1, shift) + scipy.stats.nct.cdf(-critical, maps - 1, shift)


def test_the_power_rule_sets_a_cells_maps_between_its_minimum_and_its_cap():
    exact = _cell("S4", {"best": 0.0, "advice": 0.0, "sham": 0.0})  # no spread: every power is 1
    noisy = _cell("S6", {"best": 0.0, "advice": 0.0}, spread=0.05)
    hopeless = _cell("D4", {"best": 0.0}, spread=2.0)
    cells = {c.cell: c for c in maps_per_cell(V3, exact + noisy + hopeless + _cell("L2", {"best": 0.0}))}
    assert cells["S4"].maps == 40 and cells["S4"].alpha == pytest.approx(0.05 / 2)  # sham is a control
    assert cells["D4"].maps == 60 and cells["D4"].comparisons[0].needed == 61  # the cap binds
    assert cells["D4"].comparisons[0].power_at_maps < 0.8
    # S6: the spread is in score units; a normalised score divides by (oracle - random), which the maps' random
    # teams set; whatever the value, M is the fewest maps with 80% power by the noncentral t, worked out here.
    s6 = cells["S6"]
    assert 40 <= s6.maps <= 120
    for c in s6.comparisons:
        assert _t_power(c.sigma_map, c.sigma_run, c.needed) >= 0.8 > _t_power(c.sigma_map, c.sigma_run, c.needed - 1)
    assert s6.maps == max(40, *(c.needed for c in s6.comparisons))


def _results(tmp_path: Path, runs: list[RunData]) -> Path:
    results = tmp_path / "results"
    write_data(results / "data" / "sarsa.jsonl", runs)
    write_manifest(
        results / "data", {"edition": "v3", "experiments": {"sarsa": {"profile": "full", "runs": len(runs)}}}
    )
    return results


def test_the_report_gives_each_cells_outcomes_verdict_and_controls_from_the_data_alone(tmp_path):
    # best: +0.2 of the optimum on every unit (far above the SESOI once normalised); advice: exactly none's;
    # sham: none's; warm: +0.2. So best is better, advice equivalent, the controls as they must be.
    runs = _cell("S4", {"best": 0.2, "advice": 0.0, "sham": 0.0, "warm": 0.2})
    results = _results(tmp_path, runs)
    powers = [ComparisonPower("best", 0.01, 0.02, 30, 0.93), ComparisonPower("advice", 0.1, 0.2, 200, 0.41)]
    write_maps(results, [CellMaps("S4", 40, 3, 0.025, powers)])
    report = write_report(V3, results, results).read_text()
    assert "from the pilot's variance: best 93%, advice 41%; below 80%: advice." in report
    assert "| S4 | advice − none | 0.1000 | 0.2000 | > 199 | 41% | 40 |" in report  # maps.md, included
    assert "| S4 | SARSA, treasure hunt 6x6, 2 agents | 4 × 3 |" in report
    assert "**SUPPORTED**" in report and "NOT VALIDATED" not in report
    rows = {line.split(" | ")[0][2:]: line for line in report.splitlines() if line.startswith("| ") and " − " in line}
    assert rows["best − none"].endswith("| better |") and rows["advice − none"].endswith("| equivalent |")
    assert rows["sham − none"].endswith("| equivalent |") and rows["warm − none"].endswith("| better |")
    assert "> **Not yet run**: double_dqn, lbf, figure1, figure1_maps, figure2, figure2_maps." in report
    again = write_report(V3, results, tmp_path / "elsewhere")
    assert again.read_text() == report
    assert (tmp_path / "elsewhere" / "cells.png").read_bytes() == (results / "cells.png").read_bytes()


def test_a_failed_control_marks_the_verdict_not_validated_and_sets_each_method_against_the_sham(tmp_path):
    runs = _cell("S4", {"best": 0.0, "sham": 0.2, "warm": 0.2})  # the sham "helps": the control failed
    report = write_report(V3, _results(tmp_path, runs), tmp_path / "report").read_text()
    assert "**NO USEFUL EFFECT, NOT VALIDATED (sham failed)**" in report
    assert "| best − sham |" in report


# ------------------------------------------------------------------------------------------- the command line


def test_the_pilot_without_the_tuning_stops_in_one_line_and_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "v3"
    assert study.main(["pilot", "--edition", "v3", "--out", str(out), "--launcher", "basic"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run the tune stage first" in err
    assert not out.exists()


def test_tuned_values_of_an_edition_with_tuning_cells_are_not_applied_to_the_configs(tmp_path, capsys):
    assert study.main(["tune", "--edition", "v3", "--out", str(tmp_path), "--apply"]) == 1
    assert "--apply has nothing to do" in capsys.readouterr().err


def test_the_stage_times_add_up_the_attempts(tmp_path):
    record_stage(tmp_path, "pilot", 60.0)
    record_stage(tmp_path, "pilot", 30.04)
    record_stage(tmp_path, "tune", 12.0)
    assert json.loads((tmp_path / "stages.json").read_text()) == {"pilot": [60.0, 30.0], "tune": [12.0]}


def test_a_repeat_of_the_study_is_reported_with_its_times_and_whether_its_records_are_these(tmp_path, capsys):
    runs = _cell("S4", {"best": 0.2})
    results = _results(tmp_path / "first", runs)
    record_stage(results, "tune", 600.0)
    again = _results(tmp_path / "again", runs)  # the same run records, written by another execution
    made = {"commit": "abc1234", "date": "2026-12-08", "machine": "a 2-core box", "profile": "full", "runs": len(runs)}
    write_manifest(again / "data", {"edition": "v3", "experiments": {"sarsa": made}})
    record_stage(again, "tune", 300.0)
    record_stage(again, "pilot", 120.0)
    assert report_cli.main([str(results), "--repeat", str(again), "--out", str(tmp_path / "out")]) == 0
    report = (tmp_path / "out" / "REPORT.md").read_text()
    assert "(abc1234; 2026-12-08; a 2-core box):\nits run records are these, byte for byte" in report
    assert "| pilot | 1 | 2.0 min |\n| tune | 1 | 5.0 min |\n| all | | 7.0 min (target 120 min) |" in report
    assert "| tune | 1 | 10.0 min |" in report  # the first execution's own times stay
    write_data(again / "data" / "sarsa.jsonl", _cell("S4", {"best": 0.21}))  # another result: not these records
    assert report_cli.main([str(results), "--repeat", str(again), "--out", str(tmp_path / "out")]) == 0
    assert "its run records **differ** from these" in (tmp_path / "out" / "REPORT.md").read_text()
    capsys.readouterr()
    (results / "repeat.json").unlink()
    assert report_cli.main([str(results), "--repeat", str(tmp_path / "unfinished")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a finished study" in err and not (results / "repeat.json").exists()
    (again / "stages.json").write_text("{")  # cut short
    assert report_cli.main([str(results), "--repeat", str(again)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "stages.json is not valid JSON" in err and not (results / "repeat.json").exists()
