"""dqn_transfer.experiments and its CLIs: the report on synthetic runs whose verdicts are known by construction,
and the experiment configs compose. Nothing is trained here (the real sweeps are `reproduce.py --profile quick`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dqn_transfer.analysis.plots import group_runs
from dqn_transfer.analysis.runs import find_run_dirs
from dqn_transfer.cli import plot, report
from dqn_transfer.experiments import sweeps
from dqn_transfer.config import CONFIG_DIR, register_configs, validate
from dqn_transfer.enums import Algorithm, Mode
from dqn_transfer.enums import values as enum_values
from dqn_transfer.experiments.claims import team_size
from dqn_transfer.experiments.report import write_report
from dqn_transfer.experiments.sweeps import (
    EXPERIMENTS,
    PROFILES,
    ReproduceError,
    count_jobs,
    installed_launchers,
    launcher_overrides,
    sweep_overrides,
)
from dqn_transfer.experiments.team_maps import write_team_maps
from dqn_transfer.run_dir import RunDir

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
COMPETITIVE, COOPERATIVE, DELIBERATIVE = enum_values(Mode)
register_configs()

STEPS = np.arange(0, 1001, 100)
SEEDS = range(5)


def _seed_noise(seed: int) -> np.ndarray:
    """Per-seed wiggle shared by every condition of that seed (so paired differences are exact)."""
    return np.random.default_rng(seed).normal(0.0, 3.0, size=STEPS.size)


def _write_run(run_dir: Path, values: np.ndarray, *, seed: int, mode: str = COMPETITIVE, agents: int = 2,
               treasures: int = 1, algorithm: str = Algorithm.sarsa.value, transfer: bool = False,
               success: np.ndarray | None = None) -> None:
    """A run directory as the trainer leaves it: .hydra/config.yaml + metrics.jsonl."""
    files = RunDir(run_dir)
    files.hydra_dir.mkdir(parents=True)
    config = {
        "seed": seed, "total_steps": int(STEPS[-1]), "eval_every": 100, "eval_episodes": 5,
        "env": {"size": 6, "num_treasures": treasures, "num_traps": 1, "num_agents": agents, "mode": mode,
                "layout": None, "layout_file": None},
        "agent": {"algorithm": algorithm, "eps_start": 1.0},
        "transfer": {"enabled": transfer, "source": None, "pretrain_steps": 500, "epsilon_start": 0.3},
    }
    files.config.write_text(yaml.safe_dump(config))
    success = np.clip(values / 100.0, 0, 1) if success is None else success
    lines = [json.dumps({"step": int(s), "team_return": float(v), "success_rate": float(p)})
             for s, v, p in zip(STEPS, values, success)]
    files.metrics.write_text("\n".join(lines) + "\n")


def _make_results(out: Path, *, coop_bonus: float, delib_bonus: float) -> None:
    """fig1, fig2 and transfer sweeps; ``*_bonus`` sets the true effect of each mode."""
    ramp = np.linspace(-50.0, 50.0, STEPS.size)
    job = 0
    for mode, bonus in ((COMPETITIVE, 0.0), (COOPERATIVE, coop_bonus)):
        for seed in SEEDS:
            _write_run(out / "fig1" / str(job), ramp + bonus + _seed_noise(seed), seed=seed, mode=mode)
            job += 1
    job = 0
    for m in (1, 2, 3):
        for mode, per_agent in ((COMPETITIVE, 0.0), (COOPERATIVE, coop_bonus), (DELIBERATIVE, delib_bonus)):
            for seed in SEEDS:
                values = 10.0 * m + ramp + per_agent * (m - 1) + _seed_noise(seed)
                _write_run(out / "fig2" / str(job), values, seed=seed, mode=mode, agents=m, treasures=3)
                job += 1
    job = 0
    # double_dqn: transfer shifts the whole curve up by 20 (jumpstart and area > 0): SUPPORTED.
    # sarsa: transfer shifts it down by 10: NOT SUPPORTED.  So the claim is PARTLY SUPPORTED.
    for algorithm, shift in ((Algorithm.double_dqn.value, 20.0), (Algorithm.sarsa.value, -10.0)):
        for enabled in (False, True):
            for seed in SEEDS:
                values = ramp + (shift if enabled else 0.0) + _seed_noise(seed)
                _write_run(out / "transfer" / str(job), values, seed=seed, algorithm=algorithm, transfer=enabled)
                job += 1


def _check_pngs(out: Path, text: str) -> None:
    for name in ("fig1.png", "fig2.png", "fig2_curves.png", "transfer.png"):
        path = out / name
        assert path.read_bytes()[:8] == PNG_MAGIC, f"{name} is not a PNG"
        assert path.stat().st_size > 5000
        assert f"]({name})" in text  # the report shows it


def _claim_rows(text: str) -> dict[str, str]:
    rows = [line for line in text.splitlines() if line.startswith("| ") and "**" in line]
    return {row.split("|")[1].strip()[:1]: row.split("|")[2].strip() for row in rows}


def test_report_states_the_verdicts_known_by_construction(tmp_path):
    _make_results(tmp_path, coop_bonus=0.0, delib_bonus=15.0)
    report_path = write_report(tmp_path, profile="full")
    text = report_path.read_text()
    verdicts = _claim_rows(text)
    # claim 1: cooperation = competition exactly -> difference 0, CI [0, 0] inside the margin
    assert verdicts["1"] == "**SUPPORTED**"
    # claim 2: coop = comp at every size -> "cooperative > competitive" fails although delib > coop
    assert verdicts["2"] == "**NOT SUPPORTED**"
    assert "not established: cooperative > competitive" in text
    # claim 3: supported for double_dqn, not for sarsa
    assert verdicts["3"] == "**PARTLY SUPPORTED**"
    assert "Verdict for double_dqn: **SUPPORTED**" in text
    assert "Verdict for sarsa: **NOT SUPPORTED**" in text
    assert "5 seeds per mode" in text and "1,000 environment steps per run" in text
    assert "Sanity check passed" in text  # team of 1: competitive == cooperative
    assert "SMOKE RUN" not in text
    assert "| jumpstart |" in text and "time_to_threshold/difference" in text
    _check_pngs(tmp_path, text)


def test_report_when_cooperation_and_deliberation_help(tmp_path):
    _make_results(tmp_path, coop_bonus=30.0, delib_bonus=60.0)
    text = write_report(tmp_path, profile="quick").read_text()
    verdicts = _claim_rows(text)
    assert verdicts["1"] == "**NOT SUPPORTED**"  # cooperation is 30 better: far above the 5% margin
    assert verdicts["2"] == "**SUPPORTED**"  # delib > coop > comp at team size 3
    assert "SMOKE RUN" in text and "NOT evidence" in text  # a quick profile is never evidence


def test_report_without_runs_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ReproduceError, match="holds no runs"):
        write_report(tmp_path)
    assert report.main(["--out", str(tmp_path), "--report-only"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"error: {tmp_path.resolve()} holds no runs of fig1, fig2, transfer: run the experiments first"]


def test_team_maps_share_one_map(tmp_path):
    paths = write_team_maps(tmp_path)
    layouts = [p.read_text().strip() for p in paths]
    assert [sum(ch.isdigit() for ch in layout) for layout in layouts] == list(range(1, len(layouts) + 1))
    strip = [layout.translate(str.maketrans("0123456789", ".........." )) for layout in layouts]
    assert len(set(strip)) == 1  # the same obstacles, chests and traps for every team size
    config = {"env": {"layout_file": str(paths[1]), "num_agents": None}}
    assert team_size(config) == 2


def test_plot_groups_runs_by_their_config_differences(tmp_path, capsys):
    _make_results(tmp_path, coop_bonus=0.0, delib_bonus=0.0)
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
    bimodal = [(steps, np.array([0.0, 90.0, 100.0])), (steps, np.array([0.0, -90.0, -100.0])),
               (steps, np.array([0.0, 95.0, 100.0]))]
    fig, ax = plt.subplots()
    _band_panel(ax, "team_return", {"cooperative": bimodal}, np.random.default_rng(0), None, "environment steps", "best")
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
    RunDir(chained).metrics.write_text(json.dumps({"step": 0, "team_return": 1.0, "transfer_source": stage_two})
                                       + "\n" + json.dumps({"step": 10, "team_return": 2.0}) + "\n")
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
        *map(_stub_line, stubs), "error: no usable run directory among the 2 given (2 skipped)"]
    assert plot.main([str(stubs[0]), "--out", str(out)]) == 1  # one directory: its reason is the error
    assert capsys.readouterr().err.splitlines() == [f"error: {stubs[0]}: no metrics.jsonl (train.log: {REFUSED})"]
    assert not out.exists()


def test_report_skips_unusable_runs_and_keeps_its_verdicts(tmp_path, capsys):
    _make_results(tmp_path, coop_bonus=0.0, delib_bonus=15.0)  # the data of the first report test
    stub = _write_stub(tmp_path / "fig1" / "10")
    no_config = tmp_path / "fig2" / "45"  # evaluations, but which condition is it?
    no_config.mkdir()
    RunDir(no_config).metrics.write_text('{"step": 0, "team_return": 1000.0}\n')
    assert report.main(["--out", str(tmp_path), "--report-only"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        _stub_line(stub), f"skipped {no_config}: no readable .hydra/config.yaml (cannot tell its condition)"]
    verdicts = _claim_rows((tmp_path / "REPORT.md").read_text())
    assert verdicts == {"1": "**SUPPORTED**", "2": "**NOT SUPPORTED**", "3": "**PARTLY SUPPORTED**"}
    assert "5 seeds per mode" in (tmp_path / "REPORT.md").read_text()


# ------------------------------------------------------------------------------------ the launcher

@pytest.fixture
def no_sweeps(monkeypatch, tmp_path):
    """report.main with the sweeps and the report replaced by recorders: [(experiment, launcher)]."""
    calls = []
    monkeypatch.setattr(report, "run_experiment", lambda name, profile, out, launcher, *rest: calls.append(
        (name, launcher)))
    (tmp_path / "REPORT.md").write_text("# report\n")
    monkeypatch.setattr(report, "write_report", lambda out, profile: tmp_path / "REPORT.md")
    return calls


def test_without_the_sweep_extra_the_sweeps_run_one_at_a_time(monkeypatch, tmp_path, capsys, no_sweeps):
    monkeypatch.setattr(sweeps, "installed_launchers", lambda: ["basic"])  # the dev extra only
    assert report.main(["--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == ("the joblib launcher is not installed: running one job at a time with Hydra's basic "
                        'launcher (for --n-jobs at a time: pip install -e ".[sweep]")')
    assert no_sweeps == [(name, "basic") for name in EXPERIMENTS]
    assert launcher_overrides("basic", 2) == []  # no hydra/launcher override: Hydra's own launcher


def test_with_the_sweep_extra_the_default_is_joblib(monkeypatch, tmp_path, capsys, no_sweeps):
    monkeypatch.setattr(sweeps, "installed_launchers", lambda: ["basic", "joblib"])
    assert report.main(["--out", str(tmp_path), "--n-jobs", "3"]) == 0
    assert "not installed" not in capsys.readouterr().out
    assert no_sweeps == [(name, "joblib") for name in EXPERIMENTS]
    assert launcher_overrides("joblib", 3) == ["hydra/launcher=joblib", "hydra.launcher.n_jobs=3"]


@pytest.mark.parametrize("launcher, message", [
    ("submitit_slurm", 'its Hydra plugin is not installed (pip install -e ".[slurm]")'),
    ("joblib", 'its Hydra plugin is not installed (pip install -e ".[sweep]")'),
    ("slurm", "no such Hydra launcher (installed: basic)"),
])
def test_a_launcher_not_installed_is_one_error_before_anything_runs(monkeypatch, tmp_path, capsys, no_sweeps,
                                                                    launcher, message):
    monkeypatch.setattr(sweeps, "installed_launchers", lambda: ["basic"])
    assert report.main(["--out", str(tmp_path / "out"), "--launcher", launcher]) == 1
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"error: --launcher {launcher}: {message}"]
    assert captured.out == "" and no_sweeps == [] and not (tmp_path / "out").exists()


def test_hydras_basic_launcher_is_always_installed():
    assert "basic" in installed_launchers()


def _compose(*overrides: str, hydra: bool = False):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)


@pytest.mark.parametrize("experiment, algorithm, size, treasures, swept", [
    ("fig1", Algorithm.sarsa, 6, 1, {"mode"}),
    ("fig2", Algorithm.sarsa, 10, 4, {"mode", "env.num_agents"}),
    ("transfer", Algorithm.double_dqn, 6, 2, {"transfer"}),
])
def test_experiment_configs_compose(experiment, algorithm, size, treasures, swept):
    cfg = _compose(f"experiment={experiment}", hydra=True)
    assert set(cfg.hydra.sweeper.params) == swept
    assert f"multirun/{experiment}/" in OmegaConf.to_container(cfg.hydra.sweep)["dir"]
    config = OmegaConf.to_object(_compose(f"experiment={experiment}"))
    assert config.agent.algorithm.value == algorithm.value  # an enum member, not a string
    assert config.env.size == size and config.env.num_treasures == treasures
    assert config.progress is False and config.total_steps > config.eval_every
    assert config.replicas.seeds >= 10  # the seeds are replicas inside each job
    validate(config)
    # every point of the sweep composes too (one job per value, the others at their first value)
    for key, values in cfg.hydra.sweeper.params.items():
        for value in str(values).replace("range(0,", "").rstrip(")").split(",")[:3]:
            job = OmegaConf.to_object(_compose(f"experiment={experiment}", f"{key}={value}"))
            validate(job)


def test_fig1_is_one_treasure_and_the_experiment_overrides_the_defaults():
    config = OmegaConf.to_object(_compose("experiment=fig1", f"mode={COOPERATIVE}"))
    assert config.env.num_treasures == 1 and config.env.num_traps == 1 and config.env.num_agents == 2
    assert config.env.mode.value == Mode.cooperative.value
    assert config.total_steps != OmegaConf.to_object(_compose()).total_steps  # experiment wins over config.yaml


def test_profiles_seed_counts_and_job_counts(tmp_path):
    assert all(n >= 10 for n in PROFILES["full"].seeds.values())
    assert all(2 <= n <= 3 for n in PROFILES["quick"].seeds.values())
    overrides = sweep_overrides("fig2", "quick", tmp_path)
    assert count_jobs("fig2", overrides) == 3 * 4  # one job per condition, its seeds as replicas
    assert f"replicas.seeds={PROFILES['quick'].seeds['fig2']}" in overrides
    assert (tmp_path / "maps" / "fig2_m4.txt").exists()
    overrides = sweep_overrides("transfer", "full", tmp_path)
    assert count_jobs("transfer", overrides) == 2 * 2
