"""scripts/reproduce.py: the report on synthetic runs whose verdicts are known by construction, and the
experiment configs compose. Nothing is trained here (the real sweeps are `reproduce.py --profile quick`)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dqn_transfer.config import Algorithm, Mode, register_configs, validate

ROOT = Path(__file__).resolve().parent.parent
CONF_DIR = str(ROOT / "conf")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
register_configs()


def _load_script(name: str):
    path = ROOT / "scripts" / f"{name}.py"
    if str(path.parent) not in sys.path:
        sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location(f"scripts_{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


reproduce = _load_script("reproduce")
plot = _load_script("plot")

STEPS = np.arange(0, 1001, 100)
SEEDS = range(5)


def _seed_noise(seed: int) -> np.ndarray:
    """Per-seed wiggle shared by every condition of that seed (so paired differences are exact)."""
    return np.random.default_rng(seed).normal(0.0, 3.0, size=STEPS.size)


def _write_run(run_dir: Path, values: np.ndarray, *, seed: int, mode: str = "competitive", agents: int = 2,
               treasures: int = 1, algorithm: str = "sarsa", transfer: bool = False,
               success: np.ndarray | None = None) -> None:
    """A run directory as the trainer leaves it: .hydra/config.yaml + metrics.jsonl."""
    (run_dir / ".hydra").mkdir(parents=True)
    config = {
        "seed": seed, "total_steps": int(STEPS[-1]), "eval_every": 100, "eval_episodes": 5,
        "env": {"size": 6, "num_treasures": treasures, "num_traps": 1, "num_agents": agents, "mode": mode,
                "layout": None, "layout_file": None},
        "agent": {"algorithm": algorithm, "eps_start": 1.0},
        "transfer": {"enabled": transfer, "source": None, "pretrain_steps": 500, "epsilon_start": 0.3},
    }
    (run_dir / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    success = np.clip(values / 100.0, 0, 1) if success is None else success
    lines = [json.dumps({"step": int(s), "team_return": float(v), "success_rate": float(p)})
             for s, v, p in zip(STEPS, values, success)]
    (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")


def _make_results(out: Path, *, coop_bonus: float, delib_bonus: float) -> None:
    """fig1, fig2 and transfer sweeps; ``*_bonus`` sets the true effect of each mode."""
    ramp = np.linspace(-50.0, 50.0, STEPS.size)
    job = 0
    for mode, bonus in (("competitive", 0.0), ("cooperative", coop_bonus)):
        for seed in SEEDS:
            _write_run(out / "fig1" / str(job), ramp + bonus + _seed_noise(seed), seed=seed, mode=mode)
            job += 1
    job = 0
    for m in (1, 2, 3):
        for mode, per_agent in (("competitive", 0.0), ("cooperative", coop_bonus), ("deliberative", delib_bonus)):
            for seed in SEEDS:
                values = 10.0 * m + ramp + per_agent * (m - 1) + _seed_noise(seed)
                _write_run(out / "fig2" / str(job), values, seed=seed, mode=mode, agents=m, treasures=3)
                job += 1
    job = 0
    # double_dqn: transfer shifts the whole curve up by 20 (jumpstart and area > 0): SUPPORTED.
    # sarsa: transfer shifts it down by 10: NOT SUPPORTED.  So the claim is PARTLY SUPPORTED.
    for algorithm, shift in (("double_dqn", 20.0), ("sarsa", -10.0)):
        for enabled in (False, True):
            for seed in SEEDS:
                values = ramp + (shift if enabled else 0.0) + _seed_noise(seed)
                _write_run(out / "transfer" / str(job), values, seed=seed, algorithm=algorithm, transfer=enabled)
                job += 1


def _check_pngs(out: Path, report: str) -> None:
    for name in ("fig1.png", "fig2.png", "fig2_curves.png", "transfer.png"):
        path = out / name
        assert path.read_bytes()[:8] == PNG_MAGIC, f"{name} is not a PNG"
        assert path.stat().st_size > 5000
        assert f"]({name})" in report  # the report shows it


def _claim_rows(report: str) -> dict[str, str]:
    rows = [line for line in report.splitlines() if line.startswith("| ") and "**" in line]
    return {row.split("|")[1].strip()[:1]: row.split("|")[2].strip() for row in rows}


def test_report_states_the_verdicts_known_by_construction(tmp_path):
    _make_results(tmp_path, coop_bonus=0.0, delib_bonus=15.0)
    report_path = reproduce.write_report(tmp_path, profile="full")
    report = report_path.read_text()
    verdicts = _claim_rows(report)
    # claim 1: cooperation = competition exactly -> difference 0, CI [0, 0] inside the margin
    assert verdicts["1"] == "**SUPPORTED**"
    # claim 2: coop = comp at every size -> "cooperative > competitive" fails although delib > coop
    assert verdicts["2"] == "**NOT SUPPORTED**"
    assert "not established: cooperative > competitive" in report
    # claim 3: supported for double_dqn, not for sarsa
    assert verdicts["3"] == "**PARTLY SUPPORTED**"
    assert "Verdict for double_dqn: **SUPPORTED**" in report
    assert "Verdict for sarsa: **NOT SUPPORTED**" in report
    assert "5 seeds per mode" in report and "1,000 environment steps per run" in report
    assert "Sanity check passed" in report  # team of 1: competitive == cooperative
    assert "SMOKE RUN" not in report
    assert "| jumpstart |" in report and "time_to_threshold/difference" in report
    _check_pngs(tmp_path, report)


def test_report_when_cooperation_and_deliberation_help(tmp_path):
    _make_results(tmp_path, coop_bonus=30.0, delib_bonus=60.0)
    report = reproduce.write_report(tmp_path, profile="quick").read_text()
    verdicts = _claim_rows(report)
    assert verdicts["1"] == "**NOT SUPPORTED**"  # cooperation is 30 better: far above the 5% margin
    assert verdicts["2"] == "**SUPPORTED**"  # delib > coop > comp at team size 3
    assert "SMOKE RUN" in report and "NOT evidence" in report  # a quick profile is never evidence


def test_report_without_runs_is_a_clear_error(tmp_path):
    with pytest.raises(reproduce.ReproduceError, match="holds no runs"):
        reproduce.write_report(tmp_path)
    assert reproduce.main(["--out", str(tmp_path), "--report-only"]) == 1


def test_team_maps_share_one_map(tmp_path):
    paths = reproduce.write_team_maps(tmp_path)
    layouts = [p.read_text().strip() for p in paths]
    assert [sum(ch.isdigit() for ch in layout) for layout in layouts] == list(range(1, len(layouts) + 1))
    strip = [layout.translate(str.maketrans("0123456789", ".........." )) for layout in layouts]
    assert len(set(strip)) == 1  # the same obstacles, chests and traps for every team size
    config = {"env": {"layout_file": str(paths[1]), "num_agents": None}}
    assert reproduce.team_size(config) == 2


def test_plot_groups_runs_by_their_config_differences(tmp_path):
    _make_results(tmp_path, coop_bonus=0.0, delib_bonus=0.0)
    runs = plot.find_run_dirs([tmp_path / "fig1"])
    groups = plot.group_runs(runs)
    assert sorted(groups) == ["mode=competitive", "mode=cooperative"]
    assert all(len(v) == 5 for v in groups.values())
    out = tmp_path / "curves.png"
    assert plot.main([str(tmp_path / "fig1"), "--out", str(out), "--metric", "success_rate"]) == 0
    assert out.read_bytes()[:8] == PNG_MAGIC
    assert plot.main([str(tmp_path / "nowhere"), "--out", str(out)]) == 1


def _compose(*overrides: str, hydra: bool = False):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)


@pytest.mark.parametrize("experiment, algorithm, size, treasures, swept", [
    ("fig1", Algorithm.sarsa, 6, 1, {"mode", "seed"}),
    ("fig2", Algorithm.sarsa, 10, 4, {"mode", "env.num_agents", "seed"}),
    ("transfer", Algorithm.double_dqn, 6, 2, {"transfer", "seed"}),
])
def test_experiment_configs_compose(experiment, algorithm, size, treasures, swept):
    cfg = _compose(f"experiment={experiment}", hydra=True)
    assert set(cfg.hydra.sweeper.params) == swept
    assert f"multirun/{experiment}/" in OmegaConf.to_container(cfg.hydra.sweep)["dir"]
    config = OmegaConf.to_object(_compose(f"experiment={experiment}"))
    assert config.agent.algorithm is algorithm
    assert config.env.size == size and config.env.num_treasures == treasures
    assert config.progress is False and config.total_steps > config.eval_every
    validate(config)
    # every point of the sweep composes too (one job per value, the others at their first value)
    for key, values in cfg.hydra.sweeper.params.items():
        for value in str(values).replace("range(0,", "").rstrip(")").split(",")[:3]:
            job = OmegaConf.to_object(_compose(f"experiment={experiment}", f"{key}={value}"))
            validate(job)


def test_fig1_is_one_treasure_and_the_experiment_overrides_the_defaults():
    config = OmegaConf.to_object(_compose("experiment=fig1", "mode=cooperative"))
    assert config.env.num_treasures == 1 and config.env.num_traps == 1 and config.env.num_agents == 2
    assert config.env.mode is Mode.cooperative
    assert config.total_steps != OmegaConf.to_object(_compose()).total_steps  # experiment wins over config.yaml


def test_profiles_seed_counts_and_job_counts(tmp_path):
    assert all(n >= 10 for n in reproduce.PROFILES["full"].seeds.values())
    assert all(2 <= n <= 3 for n in reproduce.PROFILES["quick"].seeds.values())
    overrides = reproduce.sweep_overrides("fig2", "quick", tmp_path)
    assert reproduce.count_jobs("fig2", overrides) == 3 * 4 * reproduce.PROFILES["quick"].seeds["fig2"]
    assert (tmp_path / "maps" / "fig2_m4.txt").exists()
    overrides = reproduce.sweep_overrides("transfer", "full", tmp_path)
    assert reproduce.count_jobs("transfer", overrides) == 2 * 2 * reproduce.PROFILES["full"].seeds["transfer"]
