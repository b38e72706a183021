"""dqn_transfer.experiments and its CLIs: the report on synthetic runs whose verdicts are known by construction,
and the experiment configs compose. Nothing is trained here (the real sweeps are `reproduce.py --profile quick`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPORT_DATA, missing_beside
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dqn_transfer.analysis.plots import group_runs
from dqn_transfer.analysis.runs import find_run_dirs
from dqn_transfer.cli import plot, report, study
from dqn_transfer.config import CONFIG_DIR, register_configs, validate
from dqn_transfer.enums import Algorithm, Mode
from dqn_transfer.enums import values as enum_values
from dqn_transfer.experiments import claims, pipeline, scoring, sweeps
from dqn_transfer.experiments.edition import load_edition
from dqn_transfer.experiments.raw_data import RunData, export_sweep, read_data, write_data, write_manifest
from dqn_transfer.experiments.render import Context, render
from dqn_transfer.experiments.scoring import slope
from dqn_transfer.experiments.sweeps import (
    ReproduceError,
    chosen_experiments,
    count_jobs,
    installed_launchers,
    launcher_overrides,
)
from dqn_transfer.storage.run_dir import RunDir

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
V1 = load_edition("v1")  # conf/edition/v1.yaml: the first edition
EXPERIMENTS = V1.experiments
COMPETITIVE, COOPERATIVE, DELIBERATIVE = enum_values(Mode)
register_configs()

STEPS = np.arange(0, 1001, 100)
SEEDS = range(5)


def _seed_noise(seed: int) -> np.ndarray:
    """Per-seed wiggle shared by every condition of that seed (so paired differences are exact)."""
    return np.random.default_rng(seed).normal(0.0, 3.0, size=STEPS.size)


def _write_run(
    run_dir: Path,
    values: np.ndarray,
    *,
    seed: int,
    mode: str = COMPETITIVE,
    agents: int = 2,
    treasures: int = 1,
    algorithm: str = Algorithm.sarsa.value,
    transfer: bool = False,
    success: np.ndarray | None = None,
) -> None:
    """A run directory as the trainer leaves it: .hydra/config.yaml + metrics.jsonl."""
    files = RunDir(run_dir)
    files.hydra_dir.mkdir(parents=True)
    config = {
        "seed": seed,
        "total_steps": int(STEPS[-1]),
        "eval_every": 100,
        "eval_episodes": 5,
        "env": {
            "size": 6,
            "num_treasures": treasures,
            "num_traps": 1,
            "num_agents": agents,
            "mode": mode,
            "layout": None,
            "layout_file": None,
            "step_reward": -1.0,
            "trap_reward": -100.0,
        },
        "agent": {"algorithm": algorithm, "eps_start": 1.0},
        "transfer": {"enabled": transfer, "source": None, "pretrain_steps": 500, "epsilon_start": 0.3},
    }
    files.config.write_text(yaml.safe_dump(config))
    success = np.clip(values / 100.0, 0, 1) if success is None else success
    lines = [
        json.dumps({"step": int(s), "team_return": float(v), "success_rate": float(p)})
        for s, v, p in zip(STEPS, values, success)
    ]
    files.metrics.write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------------ the report, from raw data

MAPS, RUN_SEEDS = range(5), range(2)


def _record(
    experiment: str,
    name: str,
    values: np.ndarray,
    *,
    map_seed: int,
    seed: int,
    algorithm: str = "sarsa",
    mode: str = COOPERATIVE,
    agents: int = 2,
    exchange: str = "none",
    share: bool = False,
    transfer: bool = False,
    eps_start: float = 1.0,
    steps_before: int = 0,
    optimum: float | None = 100.0,
    curriculum: dict | None = None,
    **transfer_keys,
) -> RunData:
    """One run's raw data as the export writes it (only the config keys the report reads)."""
    env = {"size": 6, "num_treasures": agents, "num_traps": agents, "complexity": 0.1, "layout": None}
    config = {
        "seed": seed,
        "total_steps": int(STEPS[-1]),
        "eval_every": 100,
        "eval_episodes": 5,
        "env": {
            **env,
            "map_seed": map_seed,
            "mode": mode,
            "num_agents": agents,
            "step_reward": -1.0,
            "trap_reward": -100.0,
        },
        "agent": {"algorithm": algorithm, "eps_start": eps_start, "share_parameters": share},
        "transfer": {
            "enabled": transfer,
            "exchange": exchange,
            "exchange_every": 20,
            "exchange_tau": 0.5,
            "epsilon_start": 0.3,
            **transfer_keys,
        },
        "curriculum": curriculum or {"stages": []},
    }
    zeros = tuple(0.0 for _ in STEPS)
    metrics = {
        "team_return": tuple(float(v) for v in values),
        "success_rate": zeros,
        "trap_rate": zeros,
        "after_clear_rate": zeros,
        "return_after_clear": zeros,
    }
    return RunData(experiment, name, config, tuple(int(s) for s in STEPS), metrics, steps_before, optimum)


def _noise(map_seed: int, seed: int) -> np.ndarray:
    """A unit's wiggle, shared by every condition of that (map, seed): paired differences cancel it."""
    return np.random.default_rng([map_seed, seed]).normal(0.0, 2.0, size=STEPS.size)


def _study_data(
    data: Path, *, exchange_gain: float, coop_gain: float, trend: float, transfer_gain: float, profile: str = "full"
) -> None:
    """Raw data of every experiment with effects known by construction (the optimum is 100, so a score
    point is a return unit):

    - hypothesis: exchange=best adds ``exchange_gain`` to every evaluation;
    - claim1: cooperative adds ``coop_gain`` return units, plus up to +-1 that differs between units;
    - claim2: at team size m, cooperative adds ``trend * m`` over competitive and deliberative as much again;
    - transfer: same_map adds ``transfer_gain`` over the exploration-matched baseline.
    """
    ramp = np.linspace(10.0, 60.0, STEPS.size)
    units = [(m, s) for m in MAPS for s in RUN_SEEDS]
    jitter = {u: np.random.default_rng(list(u)).uniform(-1.0, 1.0) for u in units}
    runs: dict[str, list[RunData]] = {"hypothesis": [], "claim1": [], "claim2": [], "transfer": []}
    for job, (algorithm, mode, exchange) in enumerate(
        (a, m, e) for a in ("sarsa", "double_dqn") for m in (COOPERATIVE, DELIBERATIVE) for e in ("none", "best")
    ):
        gain = exchange_gain if exchange == "best" else 0.0
        runs["hypothesis"] += [
            _record(
                "hypothesis",
                f"{job}/{u}",
                ramp + gain + _noise(*u),
                map_seed=u[0],
                seed=u[1],
                algorithm=algorithm,
                mode=mode,
                agents=4,
                exchange=exchange,
            )
            for u in units
        ]
    for job, mode in enumerate((COMPETITIVE, COOPERATIVE)):
        runs["claim1"] += [
            _record(
                "claim1",
                f"{job}/{u}",
                ramp + _noise(*u) + (coop_gain + jitter[u] if job else 0.0),
                map_seed=u[0],
                seed=u[1],
                mode=mode,
                optimum=None,
            )
            for u in units
        ]
    job = 0
    for algorithm in ("sarsa", "double_dqn"):
        for m in (2, 3, 4, 6):
            for k, mode in enumerate((COMPETITIVE, COOPERATIVE, DELIBERATIVE)):
                runs["claim2"] += [
                    _record(
                        "claim2",
                        f"{job}/{u}",
                        ramp + k * trend * m + _noise(*u) + jitter[u] * k,
                        map_seed=u[0],
                        seed=u[1],
                        algorithm=algorithm,
                        mode=mode,
                        agents=m,
                    )
                    for u in units
                ]
                job += 1
    conditions = {
        "scratch_matched": ({"transfer": False, "eps_start": 0.3}, 0.0),
        "scratch": ({"transfer": False}, -5.0),
        "same_map": ({"transfer": True, "steps_before": 500}, transfer_gain),
        "team_member": ({"transfer": True, "steps_before": 500, "source_task": "team"}, 0.0),
    }
    for job, (algorithm, (keys, gain)) in enumerate(
        (a, c) for a in ("sarsa", "double_dqn") for c in conditions.values()
    ):
        runs["transfer"] += [
            _record(
                "transfer",
                f"{job}/{u}",
                ramp + gain + _noise(*u),
                map_seed=u[0],
                seed=u[1],
                algorithm=algorithm,
                **keys,
            )
            for u in units
        ]
    # curriculum: 300 steps on a room, then the map for the last 700; scratch 1,000 on the map
    room = {"stages": [{"env": {"size": 5, "num_agents": 1}, "steps": 300}]}
    runs["curriculum"] = [
        _record(
            "curriculum",
            f"{job}/{s}",
            values,
            map_seed=0,
            seed=s,
            algorithm=algorithm,
            steps_before=before,
            **({"curriculum": room} if before else {}),
        )
        for job, (algorithm, before) in enumerate((a, b) for a in ("sarsa", "double_dqn") for b in (0, 300))
        for s in range(10)
        for values in [ramp + _noise(0, s)]
    ]
    for name, records in runs.items():
        write_data(data / f"{name}.jsonl", records)
    write_manifest(
        data,
        {
            "edition": "v1",
            "profile": profile,
            "commit": "abc1234",
            "rules_commit": "def5678 2026-12-02",
            "machine": "test machine",
            "runs": {k: len(v) for k, v in runs.items()},
            "wall_seconds": {"claim1": 10.0},
            "date": "2026-12-02",
        },
    )


def _verdicts(text: str) -> dict[str, str]:
    rows = [line for line in text.splitlines() if line.startswith("| ") and "**" in line]
    return {row.split("|")[1].strip().split(":")[0]: row.split("|")[4].strip() for row in rows}


def test_the_report_states_the_verdicts_known_by_construction(tmp_path):
    _study_data(tmp_path / "data", exchange_gain=20.0, coop_gain=0.0, trend=3.0, transfer_gain=15.0)
    text = pipeline.write_report(V1, tmp_path).read_text()
    assert _verdicts(text) == {
        "Main hypothesis": "**SUPPORTED**",  # best beats none on every map: P = 1
        "Claim 1": "**SUPPORTED**",  # coop - comp within +-1 return unit, margin +5
        "Claim 2": "**SUPPORTED**",  # both gaps grow by 3 points per agent
        "Claim 3": "**SUPPORTED**",  # same_map 15 points above the matched baseline
        "Curriculum": "**EXPLORATORY**",
    }  # no rule, no verdict
    assert "committed at def5678 2026-12-02" in text and "SMOKE RUN" not in text
    # the team-member source is no better than the baseline: it never pays for its 500 steps
    row = next(line for line in text.splitlines() if line.startswith("| sarsa | team_member |"))
    assert "| 500 |" in row and row.endswith("| never |")
    for figure in (
        "hypothesis.png",
        "hypothesis_profiles.png",
        "claim1.png",
        "claim2.png",
        "claim2_trend.png",
        "transfer.png",
        "transfer_total_steps.png",
        "curriculum.png",
    ):
        assert (tmp_path / figure).read_bytes()[:8] == PNG_MAGIC and f"]({figure})" in text


def test_the_report_says_when_the_data_contradict_or_do_not_support_a_claim(tmp_path):
    _study_data(tmp_path / "data", exchange_gain=-20.0, coop_gain=30.0, trend=-3.0, transfer_gain=0.0, profile="quick")
    text = pipeline.write_report(V1, tmp_path).read_text()
    assert _verdicts(text) == {
        "Main hypothesis": "**CONTRADICTED**",  # exchange hurts on every map
        "Claim 1": "**NOT SUPPORTED**",  # cooperation is 30 better, far above +5
        "Claim 2": "**CONTRADICTED**",  # the gaps shrink with the team
        "Claim 3": "**NOT SUPPORTED**",  # identical curves: P = 0.5
        "Curriculum": "**EXPLORATORY**",
    }
    assert "SMOKE RUN" in text and "NOT evidence" in text  # a quick profile is never evidence


def test_the_curriculum_is_compared_on_total_steps():
    # The curriculum run's curve is the scratch run's, shifted 300 steps later (same seed, same ramp): on
    # total steps it starts at the scratch run's step-0 value, 300 steps after the scratch run was there.
    ramp = np.linspace(10.0, 60.0, STEPS.size)  # +5 per 100 steps
    scratch = _record("curriculum", "0/0", ramp, map_seed=0, seed=0)
    curriculum = _record(
        "curriculum",
        "1/0",
        ramp,
        map_seed=0,
        seed=0,
        steps_before=300,
        curriculum={"stages": [{"env": {"size": 5}, "steps": 300}]},
    )
    ctx = Context(Path("/nonexistent"), np.random.default_rng(0))
    section = render(claims.curriculum([scratch, curriculum], ctx.rng), ctx)
    row = next(line for line in section.markdown.splitlines() if line.startswith("| sarsa |"))
    # at total step 300: curriculum 10 (its step 0) - scratch 25 (its step 300) = -0.15 of the optimum 100
    assert row.split("|")[3].strip().startswith("-0.15")


def test_the_slope_of_a_gap_over_team_size_has_the_regression_t_interval_worked_by_hand():
    rng = np.random.default_rng(0)
    # per-m means 1, 2, 3 -> slope 1; regression of the 6 points: residuals +-1, SSE 6, s^2 = 6 / 4,
    # Sxx = 4 -> stderr sqrt(1.5 / 4) = 0.6124, t(0.975, 4) = 2.7764 -> 1 +- 1.700
    point, boot, t = slope({2: np.array([0.0, 2.0]), 3: np.array([1.0, 3.0]), 4: np.array([2.0, 4.0])}, rng)
    assert point == pytest.approx(1.0) and boot.low <= 1.0 <= boot.high
    assert (t.low, t.high) == pytest.approx((1 - 1.7004, 1 + 1.7004), abs=1e-3)
    flat, boot, _ = slope({2: np.array([5.0, 5.0]), 3: np.array([5.0, 5.0]), 6: np.array([5.0, 5.0])}, rng)
    assert flat == pytest.approx(0.0) and boot.low == pytest.approx(0.0) and boot.high == pytest.approx(0.0)


def test_the_report_is_regenerated_from_its_data_byte_for_byte(tmp_path):
    _study_data(tmp_path / "results" / "data", exchange_gain=5.0, coop_gain=1.0, trend=1.0, transfer_gain=5.0)
    assert report.main([str(tmp_path / "results")]) == 0
    assert report.main([str(tmp_path / "results"), "--out", str(tmp_path / "again")]) == 0
    assert (tmp_path / "again" / "REPORT.md").read_bytes() == (tmp_path / "results" / "REPORT.md").read_bytes()
    for figure in ("claim2.png", "hypothesis_profiles.png"):
        assert (tmp_path / "again" / figure).read_bytes() == (tmp_path / "results" / figure).read_bytes()
    # What it says is beside it is there, and its data are named where they are, in the results directory.
    assert missing_beside(tmp_path / "again" / "REPORT.md") == []
    assert f"{REPORT_DATA} this report (one JSON line per run" in (tmp_path / "again" / "REPORT.md").read_text()


def test_report_without_data_is_a_clear_error(tmp_path, capsys):
    assert report.main([str(tmp_path)]) == 1
    assert capsys.readouterr().err.splitlines() == [f"error: {tmp_path} has no data/ directory of run data"]
    (tmp_path / "data").mkdir()  # data, but no manifest naming their edition
    assert report.main([str(tmp_path)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"error: {tmp_path}/data/manifest.json names no edition: pass --edition (v1, v2, v3)"
    ]
    assert study.main(["full", "--edition", "v1", "--out", str(tmp_path), "--report-only"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"error: {tmp_path.resolve()}/runs holds no runs of {', '.join(EXPERIMENTS)}: run the experiments first"
    ]


def test_exported_runs_keep_their_config_evaluations_and_map_optimum(tmp_path):
    sweep = tmp_path / "runs" / "claim2"
    layout = "0T.\n...\n.T1"  # each agent is 1 move from a chest: the optimum is 2 x 100
    for job, seed in enumerate((3, 4)):
        _write_run(sweep / str(job), STEPS * 0.1, seed=seed)
        config = yaml.safe_load(RunDir(sweep / str(job)).config.read_text())
        config["env"].update(layout=layout, num_treasures=2, num_traps=0, num_agents=2, size=3, map_seed=0)
        config["transfer"] = {"cache_dir": str(tmp_path / "study" / "pretrained")}  # where the sweep put it
        config["curriculum"] = {"cache_dir": "stages"}  # a relative one names no machine
        RunDir(sweep / str(job)).config.write_text(yaml.safe_dump(config))
    runs = export_sweep(sweep, "claim2")
    assert [r.name for r in runs] == ["0", "1"] and [r.seed for r in runs] == [3, 4]
    assert [(r.config["transfer"]["cache_dir"], r.config["curriculum"]["cache_dir"]) for r in runs] == [
        ("pretrained", "stages")
    ] * 2
    assert str(tmp_path) not in json.dumps([r.to_json() for r in runs])
    assert runs[0].optimal_return == 200.0
    assert runs[0].curve()[1][-1] == pytest.approx(100.0) and runs[0].score_curve()[1][-1] == pytest.approx(0.5)
    write_data(tmp_path / "claim2.jsonl", runs)
    assert read_data(tmp_path / "claim2.jsonl") == runs


def test_plot_groups_runs_by_their_config_differences(tmp_path, capsys):
    for job, (mode, seed) in enumerate((m, s) for m in (COMPETITIVE, COOPERATIVE) for s in SEEDS):
        _write_run(tmp_path / "fig1" / str(job), STEPS * 0.1 + seed, seed=seed, mode=mode)
    runs = find_run_dirs([tmp_path / "fig1"])
    groups = group_runs(runs)
    assert sorted(groups) == [f"mode={COMPETITIVE}", f"mode={COOPERATIVE}"]
    assert all(len(v) == 5 for v in groups.values())
    out = tmp_path / "curves.png"
    assert plot.main([str(tmp_path / "fig1"), "--out", str(out), "--metric", "success_rate"]) == 0
    assert out.read_bytes()[:8] == PNG_MAGIC
    assert plot.main([str(tmp_path / "nowhere"), "--out", str(out)]) == 1
    assert capsys.readouterr().err.splitlines() == [f"error: {tmp_path / 'nowhere'}: no such directory"]


def test_a_band_shows_each_run_beside_the_mean_and_its_axes_say_what_they_measure():
    import matplotlib.pyplot as plt

    from dqn_transfer.analysis.plots import _band_panel

    steps = np.array([0.0, 10.0, 20.0])
    bimodal = [
        (steps, np.array([0.0, 90.0, 100.0])),
        (steps, np.array([0.0, -90.0, -100.0])),
        (steps, np.array([0.0, 95.0, 100.0])),
    ]
    fig, ax = plt.subplots()
    _band_panel(
        ax, "team_return", {"cooperative": bimodal}, np.random.default_rng(0), None, "environment steps", "best"
    )
    assert len(ax.lines) == 1 + 3  # the mean, then each run
    np.testing.assert_array_equal(ax.lines[2].get_ydata(), [0.0, -90.0, -100.0])  # the run the mean hides
    assert ax.lines[1].get_linewidth() < ax.lines[0].get_linewidth()
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["cooperative (n=3)"]
    assert ax.get_ylabel() == "greedy evaluation team return"
    plt.close(fig)


def test_total_steps_count_every_warm_start_behind_a_run(tmp_path, capsys):
    from dqn_transfer.analysis.runs import steps_before

    stage_two = {"source_steps": 400, "source_transfer": {"source_steps": 300, "source_transfer": None}}
    chained = tmp_path / "chained"
    RunDir(chained).metrics.parent.mkdir(parents=True)
    RunDir(chained).metrics.write_text(
        json.dumps({"step": 0, "team_return": 1.0, "transfer_source": stage_two})
        + "\n"
        + json.dumps({"step": 10, "team_return": 2.0})
        + "\n"
    )
    plain = tmp_path / "plain"
    RunDir(plain).metrics.parent.mkdir(parents=True)
    RunDir(plain).metrics.write_text(json.dumps({"step": 0, "team_return": 0.0}) + "\n")
    assert steps_before(chained) == 700 and steps_before(plain) == 0
    out = tmp_path / "total.png"
    assert plot.main([str(chained), str(plain), "--out", str(out), "--total-steps"]) == 0
    assert out.read_bytes()[:8] == PNG_MAGIC


REFUSED = "error: unknown config key 'agent.lrr' in 'agent.lrr=0.1' (did you mean agent.lr?)"


def _write_stub(run_dir: Path) -> Path:
    """What a refused run leaves: Hydra's .hydra/ record and a train.log ending with its error line."""
    files = RunDir(run_dir)
    files.hydra_dir.mkdir(parents=True)
    files.config.write_text(yaml.safe_dump({"seed": 0, "total_steps": 1000}))
    files.overrides.write_text("- agent.lrr=0.1\n")
    files.log.write_text(f"[2026-11-22 10:00:00,000][dqn_transfer.train][ERROR] - {REFUSED}\n")
    return run_dir


def _stub_line(run_dir: Path) -> str:
    return f"skipped {run_dir}: no metrics.jsonl (train.log: {REFUSED})"


def test_plot_skips_what_is_not_a_run_and_says_why(tmp_path, capsys):
    day = tmp_path / "runs" / "2026-11-22"  # the README's `scripts/plot.py outputs/runs/<date>/*/`
    for seed in (0, 1):
        _write_run(day / f"10-0{seed}-00", STEPS * 0.01 + seed, seed=seed)
    stub = _write_stub(day / "10-02-00")
    not_evaluated = day / "10-03-00"
    not_evaluated.mkdir()
    RunDir(not_evaluated).metrics.write_text("")  # created, then killed before its first evaluation
    sweep = tmp_path / "multirun"  # a sweep directory: searched, its stub job named
    _write_run(sweep / "0", STEPS * 0.01 + 2, seed=2)
    sweep_stub = _write_stub(sweep / "1")
    (sweep / "multirun.yaml").write_text("hydra: {}\n")
    out = tmp_path / "curves.png"
    given = [*sorted(day.iterdir()), sweep, sweep / "multirun.yaml"]
    assert plot.main([*map(str, given), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.out == f"wrote {out}: 3 runs in 1 group(s): all runs (3)\n"
    assert captured.err.splitlines() == [
        _stub_line(stub),
        f"skipped {not_evaluated}: metrics.jsonl holds no evaluations yet",
        _stub_line(sweep_stub),
        f"skipped {sweep / 'multirun.yaml'}: not a directory",
    ]
    assert out.read_bytes()[:8] == PNG_MAGIC


def test_plot_of_nothing_usable_is_an_error(tmp_path, capsys):
    stubs = [_write_stub(tmp_path / name) for name in ("a", "b")]
    out = tmp_path / "curves.png"
    assert plot.main([*map(str, stubs), "--out", str(out)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        *map(_stub_line, stubs),
        "error: no usable run directory among the 2 given (2 skipped)",
    ]
    assert plot.main([str(stubs[0]), "--out", str(out)]) == 1  # one directory: its reason is the error
    assert capsys.readouterr().err.splitlines() == [f"error: {stubs[0]}: no metrics.jsonl (train.log: {REFUSED})"]
    assert not out.exists()


def test_the_export_skips_unusable_runs_and_says_why(tmp_path, capsys):
    sweep = tmp_path / "runs" / "claim1"
    for job, (mode, seed) in enumerate((m, s) for m in (COMPETITIVE, COOPERATIVE) for s in SEEDS):
        _write_run(sweep / str(job), STEPS * 0.1 + seed, seed=seed, mode=mode)
    stub = _write_stub(sweep / "10")
    no_config = sweep / "11"  # evaluations, but which condition is it?
    no_config.mkdir()
    RunDir(no_config).metrics.write_text('{"step": 0, "team_return": 1000.0}\n')
    assert study.main(["full", "--edition", "v1", "--out", str(tmp_path), "--report-only"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        _stub_line(stub),
        f"skipped {no_config}: no readable .hydra/config.yaml (cannot tell its condition)",
    ]
    assert len(read_data(tmp_path / "data" / "claim1.jsonl")) == 10
    text = (tmp_path / "REPORT.md").read_text()
    assert "5 seeds per condition" in text and "## Claim 1" in text and "## Claim 2" not in text


# ------------------------------------------------------------------------------------ the launcher


@pytest.fixture
def no_sweeps(monkeypatch, tmp_path):
    """The first edition's runs stage with the runs and the report replaced by recorders: [(experiment, launcher)]."""
    calls = []
    monkeypatch.setattr(
        study,
        "run_full",
        lambda edition, names, profile, out, launcher, *rest: calls.extend((n, launcher) for n in names),
    )
    (tmp_path / "REPORT.md").write_text("# report\n")
    monkeypatch.setattr(study, "write_report", lambda edition, out: tmp_path / "REPORT.md")
    return calls


def full_v1(*args: str) -> int:
    """``python -m dqn_transfer.cli.study full --edition v1 ARGS``."""
    return study.main(["full", "--edition", "v1", *args])


def test_without_the_sweep_extra_the_sweeps_run_one_at_a_time(monkeypatch, tmp_path, capsys, no_sweeps):
    monkeypatch.setattr(sweeps, "installed_launchers", lambda: ["basic"])  # the dev extra only
    assert full_v1("--out", str(tmp_path)) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        "the joblib launcher is not installed: running one job at a time with Hydra's basic "
        'launcher (for --n-jobs at a time: pip install -e ".[sweep]")'
    )
    assert no_sweeps == [(name, "basic") for name in EXPERIMENTS]
    assert launcher_overrides("basic", 2) == []  # no hydra/launcher override: Hydra's own launcher


def test_with_the_sweep_extra_the_default_is_joblib(monkeypatch, tmp_path, capsys, no_sweeps):
    monkeypatch.setattr(sweeps, "installed_launchers", lambda: ["basic", "joblib"])
    assert full_v1("--out", str(tmp_path), "--n-jobs", "3") == 0
    assert "not installed" not in capsys.readouterr().out
    assert no_sweeps == [(name, "joblib") for name in EXPERIMENTS]
    assert launcher_overrides("joblib", 3) == ["hydra/launcher=joblib", "hydra.launcher.n_jobs=3"]


@pytest.mark.parametrize(
    "launcher, message",
    [
        ("submitit_slurm", 'its Hydra plugin is not installed (pip install -e ".[slurm]")'),
        ("joblib", 'its Hydra plugin is not installed (pip install -e ".[sweep]")'),
        ("slurm", "no such Hydra launcher (installed: basic)"),
    ],
)
def test_a_launcher_not_installed_is_one_error_before_anything_runs(
    monkeypatch, tmp_path, capsys, no_sweeps, launcher, message
):
    monkeypatch.setattr(sweeps, "installed_launchers", lambda: ["basic"])
    assert full_v1("--out", str(tmp_path / "out"), "--launcher", launcher) == 1
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"error: --launcher {launcher}: {message}"]
    assert captured.out == "" and no_sweeps == [] and not (tmp_path / "out").exists()


def test_the_launchers_of_installed_plugins_are_found():
    # The dev extra installs Hydra's submitit plugin: its launchers must be offered beside the basic one.
    assert {"basic", "submitit_local", "submitit_slurm"} <= set(installed_launchers())


def _compose(*overrides: str, hydra: bool = False):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)


@pytest.mark.parametrize(
    "experiment, algorithm, size, treasures, swept",
    [
        ("hypothesis", Algorithm.double_dqn, 8, 4, {"transfer.exchange", "mode", "agent"}),
        ("hypothesis_shared", Algorithm.double_dqn, 8, 4, {"transfer.exchange", "mode", "agent"}),
        ("claim1", Algorithm.sarsa, 6, 1, {"mode"}),
        ("claim2", Algorithm.double_dqn, 6, 2, {"env", "mode", "agent"}),
        ("transfer", Algorithm.double_dqn, 6, 2, {"condition", "agent"}),
    ],
)
def test_experiment_configs_compose(experiment, algorithm, size, treasures, swept):
    cfg = _compose(f"experiment={experiment}", hydra=True)
    assert set(cfg.hydra.sweeper.params) == swept
    assert f"multirun/{experiment}/" in OmegaConf.to_container(cfg.hydra.sweep)["dir"]
    config = OmegaConf.to_object(_compose(f"experiment={experiment}"))
    assert config.agent.algorithm.value == algorithm.value  # an enum member, not a string
    assert config.env.size == size and config.env.num_treasures == treasures
    assert config.progress is False and config.total_steps > config.eval_every
    assert config.replicas.seeds * config.replicas.maps >= 10  # maps x seeds as replicas inside each job
    validate(config)
    # every point of the sweep composes too (one job per value, the others at their first value)
    for key, values in cfg.hydra.sweeper.params.items():
        for value in str(values).split(","):
            validate(OmegaConf.to_object(_compose(f"experiment={experiment}", f"{key}={value}")))


def test_claim2_teams_have_as_many_chests_and_traps_as_agents_on_maps_that_grow():
    sizes = {}
    for m in (2, 3, 4, 6):
        env = OmegaConf.to_object(_compose("experiment=claim2", f"env=study/m{m}")).env
        assert env.num_agents == env.num_treasures == env.num_traps == m
        sizes[m] = env.size
    assert sizes == {2: 6, 3: 7, 4: 8, 6: 10}


def test_the_transfer_conditions_differ_only_in_what_they_name():
    def job(condition: str):
        return OmegaConf.to_object(_compose("experiment=transfer", f"condition={condition}"))

    matched, scratch, same, one = job("scratch_matched"), job("scratch"), job("same_map"), job("same_map_one")
    assert matched.agent.eps_start == same.transfer.epsilon_start == 0.3 and scratch.agent.eps_start == 1.0
    assert not matched.transfer.enabled and same.transfer.enabled and one.transfer.targets == [0]
    assert job("other_map").transfer.source_map_shift == 1000
    assert job("team_member").transfer.source_task.value == "team"


def _overrides(name: str, profile: str, out: Path) -> list[str]:
    """The overrides of a first-edition experiment's multirun: its caches in ``out``, then the profile's."""
    return [*pipeline.cache_overrides(V1, name, out), *V1.profile(profile).run_overrides(name)]


def test_profiles_and_job_counts(tmp_path):
    assert {name: count_jobs(name, _overrides(name, "full", tmp_path)) for name in EXPERIMENTS} == {
        "hypothesis": 3 * 2 * 2,
        "hypothesis_shared": 2,
        "claim1": 2,
        "claim2": 4 * 3 * 2,
        "transfer": 6 * 2,
        "curriculum": 2 * 2,
    }
    assert count_jobs("claim2", _overrides("claim2", "quick", tmp_path)) == 2 * 3 * 2  # two team sizes
    assert f"transfer.cache_dir='{tmp_path / 'pretrained'}'" in _overrides("transfer", "full", tmp_path)
    with pytest.raises(ReproduceError, match="unknown experiment"):
        chosen_experiments("fig1", EXPERIMENTS, 2)


REPO = Path(__file__).resolve().parents[1]


def test_the_committed_report_is_regenerated_from_the_committed_data(tmp_path):
    # results/v1/REPORT.md is what `dqn-transfer-report results/v1` writes from results/v1/data/, byte for byte:
    # every number in it can be recomputed from the repository, without the runs.
    first_edition = REPO / "results" / "v1"
    assert report.main([str(first_edition), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "REPORT.md").read_text() == (first_edition / "REPORT.md").read_text()
    figures = sorted(p.name for p in first_edition.glob("*.png"))
    assert sorted(p.name for p in tmp_path.glob("*.png")) == figures and len(figures) == 8
    for figure in figures:
        assert (tmp_path / figure).read_bytes() == (first_edition / figure).read_bytes(), figure
    assert sum(p.stat().st_size for p in (first_edition / "data").iterdir()) < 20 * 2**20  # compact


@pytest.mark.slow
def test_the_quick_study_runs_end_to_end_from_the_command_line(tmp_path, capsys):
    # Real sweeps (Hydra multirun subprocess, Hydra's basic launcher), the export and the report.
    assert full_v1("--profile", "quick", "--out", str(tmp_path), "--only", "claim1", "--launcher", "basic") == 0
    runs = read_data(tmp_path / "data" / "claim1.jsonl")
    assert len(runs) == 2 * 3  # 2 modes x 3 maps x 1 seed, each a replica of its mode's job
    assert {r.unit for r in runs} == {(m, 0) for m in range(3)}
    assert {"after_clear_rate", "return_after_clear"} <= set(runs[0].metrics) and runs[0].steps[-1] == 600
    text = (tmp_path / "REPORT.md").read_text()
    assert "SMOKE RUN" in text and "## Claim 1" in text and "with the `quick` profile" in text
    assert full_v1("--profile", "quick", "--out", str(tmp_path), "--only", "claim1", "--launcher", "basic") == 0
    assert "[claim1] reusing the 2 complete runs" in capsys.readouterr().out  # a finished sweep is not rerun


def test_the_probability_of_improvement_compares_runs_on_the_same_maps_only():
    def runs(scores: dict[int, float]) -> list[RunData]:
        return [_record("x", f"{m}", np.full(STEPS.size, v), map_seed=m, seed=0) for m, v in scores.items()]

    better = runs({0: 0.0, 1: 90.0, 2: 90.0})
    worse = runs({1: 10.0, 2: 10.0, 3: 100.0})
    # maps 1 and 2 only: better wins both (maps 0 and 3 have nothing to be compared with)
    assert scoring.improvement(better, worse, scoring.score, np.random.default_rng(0)).mean == 1.0
