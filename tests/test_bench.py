"""scripts/bench.py: every measurement runs at tiny sizes and returns positive finite figures.

No timing assertions (the machine may be shared); only that the pieces run, report the expected keys,
render the table and reject bad arguments.
"""

import importlib.util
import json
import math
from pathlib import Path

import pytest
import torch

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "bench.py"


@pytest.fixture(scope="module")
def bench():
    """The script as a module; one torch thread meanwhile (tiny nets on a busy machine), then restored."""
    spec = importlib.util.spec_from_file_location("bench", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield module
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def tiny_hp(bench):
    return {**bench.HP, "batch_size": 8, "buffer_size": 200, "learning_starts": 20, "target_update": 10,
            "hidden": [8]}


def positive_finite(value) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value) and value > 0


def test_env_throughput(bench):
    result = bench.measure_env(2, 30, seed=0)
    assert positive_finite(result["joint_steps_per_s"]) and positive_finite(result["core_steps_per_s"])


def test_training_ours_and_sb3(bench, tiny_hp):
    for measure in (bench.measure_ours_training, bench.measure_sb3_training):
        result = measure(40, 0, tiny_hp, {**bench.SOURCE_MAP, "max_steps": 10}, eval_episodes=1)
        assert positive_finite(result["steps_per_s"]) and positive_finite(result["seconds"])
        assert result["gradient_steps"] == 40 - tiny_hp["learning_starts"]
        assert 0.0 <= result["greedy_success"] <= 1.0 and math.isfinite(result["greedy_return"])


@pytest.mark.parametrize("separate", [False, True])
def test_team_step_cost(bench, tiny_hp, separate):
    result = bench.measure_team_step_cost(2, 5, 0, separate=separate, hp=tiny_hp)
    assert result["num_agents"] == 2 and result["separate"] is separate
    assert positive_finite(result["ms_per_step"])
    assert result["ms_per_agent_step"] == pytest.approx(result["ms_per_step"] / 2)


def test_update_cost(bench, tiny_hp):
    result = bench.measure_update_cost(3, 0, tiny_hp)
    assert set(result) == {"bare", "bare_batched", "ours", "sample", "sb3"}
    assert all(positive_finite(value) for value in result.values())


def test_run_benchmark_table_and_json(bench, tiny_hp, tmp_path):
    sizes = dict(env_steps=20, train_steps=30, team_steps=2, updates=2, eval_episodes=1, thread_cap_s=0.05)
    results = bench.run_benchmark("quick", 0, 1, 1, [1], sizes=sizes, hp=tiny_hp)
    for key in ("env", "training", "team", "update", "machine", "settings", "method"):
        assert key in results
    assert [row["num_agents"] for row in results["env"]] == list(bench.ENV_AGENTS)
    assert [row["num_agents"] for row in results["team"]] == list(bench.TEAM_SIZES)
    row = results["training"][0]
    for key in ("ours_steps_per_s", "sb3_steps_per_s", "ours_over_sb3"):
        assert positive_finite(row[key])
    for key in ("bare_us", "ours_us", "sb3_us", "ours_over_bare"):
        assert positive_finite(results["update"][key])
    assert results["machine"]["cpu_count"] >= 1 and results["machine"]["torch_threads_used"] == [1]
    table = bench.render_markdown(results)
    for heading in ("## 1.", "## 2.", "## 3.", "## 4."):
        assert heading in table
    out = tmp_path / "nested" / "bench.json"
    bench.write_json(out, results)
    assert json.loads(out.read_text())["training"][0]["torch_threads"] == 1


@pytest.mark.parametrize("argv", [["--repeats", "0"], ["--threads", "x"], ["--seed", "1.5"], ["--bogus"]])
def test_bad_arguments_are_argparse_errors(bench, argv, capsys):
    with pytest.raises(SystemExit) as excinfo:
        bench.parse_args(argv)
    assert excinfo.value.code == 2
    assert "error" in capsys.readouterr().err


def test_out_directory_is_refused(bench, tmp_path):
    with pytest.raises(SystemExit):
        bench.parse_args(["--out", str(tmp_path)])
