"""The fair tuning protocol (docs/tuning.md): every search holds the same budget on tuning maps disjoint from
the evaluation maps; a quick tuning writes its trials, the chosen values and the figure; the analysis from
tuning.jsonl alone picks the best trial and refuses bad input in one line."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import compose_config
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dqn_transfer.analysis.tuning import TuningError
from dqn_transfer.cli import study
from dqn_transfer.config import CONFIG_DIR, register_configs
from dqn_transfer.experiments.tuning import apply_tuned

ROOT = Path(__file__).resolve().parents[1]


def tune(*args: str) -> int:
    """``python -m dqn_transfer.cli.study tune --edition v2 ARGS``: the tuning into ``OUT/tuning/``."""
    return study.main(["tune", "--edition", "v2", *args])


EVALUATION_MAPS = range(100)  # the study evaluates on map seeds 0 .. N-1, N up to ~100
# The protocol's search spaces, written out from the brief: each learner's step size plus its method's own keys.
STRENGTH_KEYS = {
    "sarsa_none": set(),
    "sarsa_best": {"transfer.exchange_tau", "transfer.exchange_every"},
    "sarsa_shared_replay": {"transfer.exchange_every"},
    "sarsa_confidence": {"transfer.confidence_weight", "transfer.exchange_every"},
    "sarsa_advice": {"transfer.advice_ask_below", "transfer.advice_answer_from", "transfer.advice_budget"},
    "double_dqn_none": set(),
    "double_dqn_best": {"transfer.exchange_tau", "transfer.exchange_every"},
    "double_dqn_shared_replay": {"transfer.exchange_every"},
    "double_dqn_experience": {"transfer.experience_lambda"},
    "double_dqn_shared_id": set(),
    "double_dqn_vdn": set(),
}


@pytest.fixture
def optuna_sweeper() -> None:
    """The searches' configs name Hydra's Optuna sweeper: skip without its plugin."""
    pytest.importorskip("hydra_plugins.hydra_optuna_sweeper", reason="the optuna extra: pip install -e '.[optuna]'")


def composed(name: str) -> dict:
    """The search's composed config, Hydra's part included, as plain values (enums as their names)."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"experiment=tune/{name}"], return_hydra_config=True)
    return OmegaConf.to_container(cfg, enum_to_str=True)  # type: ignore[return-value]


def test_every_search_gets_the_same_budget_on_tuning_maps_disjoint_from_the_evaluation_maps(optuna_sweeper):
    files = sorted(p.stem for p in (CONFIG_DIR / "experiment" / "tune").glob("*.yaml"))
    assert files == sorted([*STRENGTH_KEYS, "base"])
    settings = set()
    for name, keys in STRENGTH_KEYS.items():
        cfg = composed(name)
        sweeper, agent = cfg["hydra"]["sweeper"], cfg["agent"]
        learner, method = ("double_dqn", name.removeprefix("double_dqn_")) if "dqn" in name else name.split("_", 1)
        assert set(sweeper["params"]) == {"agent.lr"} | keys, name
        assert sweeper["params"]["agent.lr"].startswith("tag(log, interval("), name
        assert sweeper["sampler"]["_target_"] == "optuna.samplers.TPESampler"
        assert agent["algorithm"] == learner
        assert cfg["transfer"]["exchange"] == ("none" if method in ("shared_id", "vdn") else method)
        assert agent["mixer"] == ("vdn" if method == "vdn" else "none")
        assert agent["share_parameters"] == agent["agent_id_input"] == (method == "shared_id")
        first, count = cfg["env"]["map_seed"], cfg["replicas"]["maps"]
        maps = tuple(range(first, first + count))
        assert not set(maps) & set(EVALUATION_MAPS) and count >= 10, name
        settings.add(
            (
                sweeper["n_trials"],
                sweeper["sampler"]["seed"],
                sweeper["direction"],
                sweeper["n_jobs"],
                cfg["objective"],
                cfg["total_steps"],
                cfg["eval_every"],
                cfg["eval_episodes"],
                cfg["env"]["num_agents"],
                cfg["env"]["mode"],
                agent["engine"],
                agent["train_freq"],
                maps,
                cfg["replicas"]["seeds"],
            )
        )
    assert len(settings) == 1  # one budget, sampler, objective and set of maps for all ten searches
    ((n_trials, seed, direction, n_jobs, objective, steps, *_),) = settings
    assert (seed, direction, n_jobs, objective, steps) == (0, "maximize", 1, "mean", 8000)
    assert n_trials >= 20


# ------------------------------------------------------------------------------------ a quick tuning, end to end


def objective_of(trial_dir: Path) -> tuple[float, dict[int, float]]:
    """A trial's objective (mean over its replicas of each one's mean team return) and each map's, read
    from its files independently of the package."""
    per_map = {}
    for name in json.loads((trial_dir / "replicas.json").read_text())["replicas"]:
        returns = [
            json.loads(line)["team_return"] for line in (trial_dir / name / "metrics.jsonl").read_text().splitlines()
        ]
        seed = yaml.safe_load((trial_dir / name / ".hydra" / "config.yaml").read_text())["env"]["map_seed"]
        per_map[seed] = float(np.mean(returns))
    return float(np.mean(list(per_map.values()))), per_map


@pytest.mark.slow  # one search of two tiny trials through Hydra's Optuna sweeper: ~10 s
def test_a_quick_tuning_writes_its_trials_the_best_values_and_the_figure(optuna_sweeper, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a relative --out: the runs land under it, not under a copy of it inside it
    out = tmp_path / "tuning"
    assert tune("--out", ".", "--profile", "quick", "--only", "sarsa_best") == 0
    assert not (out / "tuning").exists()
    trial_dirs = sorted((out / "runs" / "sarsa_best").glob("[0-9]*"))
    assert [d.name for d in trial_dirs] == ["0", "1"]
    records = [json.loads(line) for line in (out / "tuning.jsonl").read_text().splitlines()]
    assert [(r["learner"], r["method"], r["trial"]) for r in records] == [("sarsa", "best", 0), ("sarsa", "best", 1)]
    expected = {}
    for record, trial_dir in zip(records, trial_dirs):
        objective, per_map = objective_of(trial_dir)
        assert record["objective"] == pytest.approx(objective)
        assert {int(k): v for k, v in record["per_map"].items()} == pytest.approx(per_map)
        assert sorted(per_map) == [1000, 1001]
        config = yaml.safe_load((trial_dir / ".hydra" / "config.yaml").read_text())
        expected[objective] = {
            "agent.lr": config["agent"]["lr"],
            "transfer.exchange_tau": config["transfer"]["exchange_tau"],
            "transfer.exchange_every": config["transfer"]["exchange_every"],
        }
        assert record["params"] == pytest.approx(expected[objective])
        assert 0.01 <= record["params"]["agent.lr"] <= 1.0 and isinstance(
            record["params"]["transfer.exchange_every"], int
        )
    tuned = yaml.safe_load((out / "tuned.yaml").read_text())
    assert tuned == {"sarsa": {"best": pytest.approx(expected[max(expected)])}}
    assert (out / "tuning_sensitivity.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| sarsa | best |" in (out / "tuning.md").read_text()
    capsys.readouterr()
    assert tune("--out", str(tmp_path), "--profile", "quick", "--only", "sarsa_best") == 0  # finished: reused
    assert "[sarsa_best] reusing the 2 complete runs" in capsys.readouterr().out


# ------------------------------------------------------------------------------------ the analysis from tuning.jsonl


SARSA_SPACE = {
    "agent.lr": {"low": 0.01, "high": 1.0, "log": True},
    "transfer.exchange_tau": {"low": 0.05, "high": 1.0, "log": False},
    "transfer.exchange_every": {"low": 1, "high": 50, "log": True},
}
DQN_SPACE = {"agent.lr": {"low": 1e-4, "high": 1e-2, "log": True}}


def record(learner, method, trial, params, objective, space):
    per_map = {"1000": objective - 1.0, "1001": objective + 1.0}  # mean: the objective
    return {
        "learner": learner,
        "method": method,
        "trial": trial,
        "params": params,
        "objective": objective,
        "objective_kind": "mean",
        "per_map": per_map,
        "space": space,
    }


def hand_written_trials() -> list[dict]:
    return [
        record(
            "sarsa",
            "best",
            0,
            {"agent.lr": 0.1, "transfer.exchange_tau": 0.5, "transfer.exchange_every": 20},
            10.0,
            SARSA_SPACE,
        ),
        record(
            "sarsa",
            "best",
            1,
            {"agent.lr": 0.5, "transfer.exchange_tau": 0.9, "transfer.exchange_every": 3},
            -5.0,
            SARSA_SPACE,
        ),
        record(
            "sarsa",
            "best",
            2,
            {"agent.lr": 0.3, "transfer.exchange_tau": 0.2, "transfer.exchange_every": 7},
            50.0,
            SARSA_SPACE,
        ),
        record("double_dqn", "none", 0, {"agent.lr": 0.002}, 30.0, DQN_SPACE),
        record("double_dqn", "none", 1, {"agent.lr": 0.0005}, 30.0, DQN_SPACE),  # a tie: the earlier trial wins
        record("double_dqn", "none", 2, {"agent.lr": 0.008}, -80.0, DQN_SPACE),
    ]


def test_searches_may_have_as_many_trials_per_searched_key_instead_of_as_many_trials(tmp_path):
    # sarsa_best: 3 trials of 3 keys; double_dqn_none: 1 trial of 1 key; the same effort per key (the third
    # edition's protocol). With 2 trials of 1 key it is neither (test_bad_trials_are_refused...).
    write_jsonl(tmp_path, hand_written_trials()[:4])
    assert tune("--out", str(tmp_path), "--report-only") == 0
    tuned = yaml.safe_load((tmp_path / "tuning" / "tuned.yaml").read_text())
    assert tuned["double_dqn"] == {"none": {"agent.lr": 0.002}}
    assert "; each search 1 trials per searched key (1 to 3)." in (tmp_path / "tuning" / "tuning.md").read_text()


def test_a_game_scored_in_0_1_gets_three_decimals_in_the_table(tmp_path):
    # LBF's team return is at most 1: the hand-written objectives / 100 (sarsa best 0.5 best, -0.05 worst).
    write_jsonl(tmp_path, [{**r, "objective": r["objective"] / 100} for r in hand_written_trials()])
    assert tune("--out", str(tmp_path), "--report-only") == 0
    assert "| sarsa | best | 2 | 0.500 | 0.100 | -0.050 .. 0.500 |" in (tmp_path / "tuning" / "tuning.md").read_text()


def write_jsonl(out: Path, records: list[dict], extra: str = "") -> None:
    """``OUT/tuning/tuning.jsonl``, as the tuning stage writes it."""
    (out / "tuning").mkdir(parents=True, exist_ok=True)
    (out / "tuning" / "tuning.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records) + extra)


def test_the_analysis_picks_each_searchs_best_trial_from_the_jsonl_alone(tmp_path, capsys):
    write_jsonl(tmp_path, hand_written_trials())
    assert tune("--out", str(tmp_path), "--report-only") == 0
    tuned = yaml.safe_load((tmp_path / "tuning" / "tuned.yaml").read_text())
    assert tuned == {
        "sarsa": {"best": {"agent.lr": 0.3, "transfer.exchange_tau": 0.2, "transfer.exchange_every": 7}},
        "double_dqn": {"none": {"agent.lr": 0.002}},
    }
    table = (tmp_path / "tuning" / "tuning.md").read_text()
    assert "| sarsa | best | 2 | 50.0 | 10.0 | -5.0 .. 50.0 |" in table
    assert "| double_dqn | none | 0 | 30.0 | 30.0 | -80.0 .. 30.0 |" in table
    assert "2 tuning maps (map seeds 1000..1001); each search 3 trials" in table
    assert (tmp_path / "tuning" / "tuning_sensitivity.png").stat().st_size > 0
    assert capsys.readouterr().err == ""


def _replace(index: int, **changes):
    def edit(records: list[dict]) -> list[dict]:
        records[index] = {**records[index], **changes}
        return records

    return edit


@pytest.mark.parametrize(
    ("edit", "extra", "message"),
    [
        (lambda r: r, "{not json\n", "tuning.jsonl:7: not valid JSON"),
        (lambda r: [], "", "tuning.jsonl: holds no trials"),
        (_replace(2, objective=math.nan), "", "tuning.jsonl:3: 'objective' is missing or not a finite number"),
        (
            _replace(0, params={"agent.lr": 2.0, "transfer.exchange_tau": 0.5, "transfer.exchange_every": 20}),
            "",
            "tuning.jsonl:1: agent.lr=2.0 is outside its search space [0.01, 1.0]",
        ),
        (_replace(3, params={}), "", "tuning.jsonl:4: 'params' has keys [], its search space ['agent.lr']"),
        (_replace(4, trial="one"), "", "tuning.jsonl:5: 'trial' is missing or not of type int"),
        (_replace(4, trial=0), "", "search double_dqn_none has a trial number twice"),
        (lambda r: r[:-1], "", "the searches have different numbers of trials (sarsa_best 3, double_dqn_none 2)"),
        (_replace(5, objective_kind="final"), "", "the trials optimise different objectives (final, mean)"),
    ],
)
def test_bad_trials_are_refused_in_one_line_and_nothing_is_written(tmp_path, capsys, edit, extra, message):
    write_jsonl(tmp_path, edit(hand_written_trials()), extra)
    assert tune("--out", str(tmp_path), "--report-only") == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert sorted(p.name for p in (tmp_path / "tuning").iterdir()) == ["tuning.jsonl"]


def test_a_missing_jsonl_and_an_unknown_search_are_one_line(tmp_path, capsys):
    assert tune("--out", str(tmp_path / "none"), "--report-only") == 1
    assert capsys.readouterr().err.startswith(f"error: {tmp_path / 'none' / 'tuning' / 'tuning.jsonl'}: cannot read it")
    assert tune("--out", str(tmp_path), "--only", "sarsa_experience") == 1
    err = capsys.readouterr().err
    assert err.startswith("error: unknown search 'sarsa_experience' (choose from sarsa_none,") and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_apply_writes_each_searchs_chosen_values_as_the_methods_tuned_option(tmp_path, capsys):
    (tmp_path / "tuned.yaml").write_text(
        "sarsa:\n  best: {agent.lr: 0.25, transfer.exchange_tau: 0.5, transfer.exchange_every: 7}\n"
        "double_dqn:\n  shared_id: {agent.lr: 0.0003}\n"
    )
    written = apply_tuned(tmp_path, tmp_path / "conf")
    assert sorted(p.name for p in written) == ["double_dqn_shared_id.yaml", "sarsa_best.yaml"]
    sarsa = yaml.safe_load((tmp_path / "conf" / "tuned" / "sarsa_best.yaml").read_text())
    assert sarsa == {"agent": {"lr": 0.25}, "transfer": {"exchange_every": 7, "exchange_tau": 0.5}}
    (tmp_path / "tuned.yaml").write_text("[1, 2]")
    with pytest.raises(TuningError, match="not a tuned.yaml"):
        apply_tuned(tmp_path, tmp_path / "conf")


def test_the_studys_methods_compose_the_committed_tuned_values():
    """results/v2/tuning/tuned.yaml (stage 2, committed) is what every method of the second edition runs with."""
    tuned = yaml.safe_load((ROOT / "results" / "v2" / "tuning" / "tuned.yaml").read_text())
    for learner, methods in tuned.items():
        for method, params in methods.items():
            config = compose_config("experiment=v2/hypothesis", f"method={learner}_{method}")
            for key, value in params.items():
                group, leaf = key.split(".")
                assert getattr(getattr(config, group), leaf) == pytest.approx(value), (learner, method, key)
