"""Inputs a new user might invent: each is refused in exactly one line (stdout and stderr together),
with a non-zero exit code, and leaves the launch directory (and any run directory it names) as it was.

Each case runs ``python train.py`` in a copy of one launch directory, which holds a valid map, a few
bad layout files and a finished ``total_steps=0`` run to misuse with ``resume=true``.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from conftest import TRAIN_PY, TRAIN_TIMEOUT, train_env

pytestmark = pytest.mark.slow  # one `python train.py` process per case

MAP = "0...T\n.#...\n...#.\nX....\n1..T.\n"
FILES = {
    "map.txt": MAP,
    "not_square.txt": "0.T\n..X\n",
    "bad_char.txt": "0.T\n.Q.\nX..\n",
    "empty.txt": "",
    "no_agent.txt": "..T\n...\nX..\n",
}

# name -> (overrides, words the one line must contain). A case without hydra.run.dir uses Hydra's default.
CASES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # type errors
    "gamma_not_a_number": (("agent.gamma=0.9x",), ("agent.gamma=0.9x", "expected a float")),
    "batch_size_float": (("agent.batch_size=32.5",), ("agent.batch_size=32.5", "expected an integer")),
    "size_word": (("env.size=big",), ("env.size=big", "expected an integer")),
    "hidden_word": (("agent.hidden=[64,abc]",), ("agent.hidden=[64,abc]", "list of integers")),
    "hidden_scalar": (("agent.hidden=64",), ("agent.hidden=64", "expected a list of integers")),
    "eval_every_list": (("eval_every=[100]",), ("eval_every", "expected an integer")),
    "progress_maybe": (("progress=maybe",), ("progress=maybe", "true or false")),
    "resume_maybe": (("resume=maybe",), ("resume=maybe", "true or false")),
    "device_tpu": (("device=tpu",), ("device=tpu", "cpu|cuda|auto")),
    "obs_encoding": (("env.obs_encoding=binary",), ("env.obs_encoding=binary", "onehot")),
    "exchange_all": (("transfer.exchange=all",), ("transfer.exchange=all", "shared_replay")),
    "engine_jax": (("agent.engine=jax",), ("agent.engine=jax", "numpy")),
    "seed_float": (("seed=1.5",), ("seed=1.5", "expected an integer")),
    "total_steps_exponent": (("total_steps=1e5",), ("total_steps=1e5", "expected an integer")),
    "sweep_with_a_bad_value": (("-m", "seed=1,abc"), ("seed=abc", "expected an integer")),
    "two_hydra_modes": (("-m", "seed=1,2", "--cfg", "job"), ("--multirun and --cfg", "one of")),
    # out of range
    "no_treasures": (("env.num_treasures=0",), ("env.num_treasures", ">= 1")),
    "eps_end_negative": (("agent.eps_end=-0.1",), ("agent.eps_end", "[0, 1]")),
    "eval_episodes_zero": (("eval_episodes=0",), ("eval_episodes", ">= 1")),
    "threads_zero": (("threads=0",), ("threads", ">= 1")),
    "view_radius_negative": (("env.view_radius=-1",), ("env.view_radius", ">= 0")),
    "eleven_agents": (("env.num_agents=11",), ("num_agents",)),
    "traps_negative": (("env.num_traps=-1",), ("num_traps",)),
    "exploration_fraction_two": (("agent.exploration_fraction=2",), ("agent.exploration_fraction", "[0, 1]")),
    "complexity_nan": (("env.complexity=nan",), ("env.complexity",)),
    "lr_infinite": (("agent.lr=inf",), ("agent.lr",)),
    "treasure_reward_nan": (("env.treasure_reward=nan",), ("treasure_reward",)),
    "negative_seed": (("seed=-1",), ("seed",)),
    "huge_seed": (("seed=99999999999999999999",), ("seed",)),
    # absurd sizes
    "size_100000": (("env.size=100000",), ("env.size=100000", "64")),
    "size_300": (("env.size=300",), ("env.size=300", "64")),
    "size_65": (("env.size=65",), ("env.size=65", "64")),
    "replay_too_big": (
        ("env.size=64", "agent.buffer_size=1000000000", "total_steps=1000000000"),
        ("memory", "replay", "available"),
    ),
    "a_billion_replicas": (("replicas.seeds=1000000000",), ("memory", "available")),
    "huge_network": (("agent.hidden=[100000000]",), ("memory", "networks")),
    "huge_tables": (
        ("agent=sarsa", "env.size=64", "total_steps=1000000000000", "replicas.seeds=1000"),
        ("memory", "Q-tables"),
    ),
    "too_many_treasures": (("env.num_treasures=100000",), ("num_treasures",)),
    # bad groups
    "env_huge": (("env=huge",), ("env=huge", "no such option")),
    "mode_telepathic": (("mode=telepathic",), ("mode=telepathic", "no such option")),
    "experiment_missing": (("experiment=nonexistent",), ("experiment=nonexistent", "no such option")),
    "curriculum_steep": (("curriculum=steep",), ("curriculum=steep", "no such option")),
    "condition_unknown": (("condition=foo",), ("condition=foo", "no such option")),
    # bad layouts
    "layout_one_row": (("env.layout=abc",), ("layout",)),
    "layout_not_square": (("env.layout_file=not_square.txt",), ("square",)),
    "layout_bad_char": (("env.layout_file=bad_char.txt",), ("Q",)),
    "layout_directory": (("env.layout_file=.",), ("env.layout_file=.", "not a regular file")),
    "layout_device": (("env.layout_file=/dev/zero",), ("/dev/zero", "not a regular file")),
    "layout_empty": (("env.layout_file=empty.txt",), ("layout",)),
    "layout_no_agent": (("env.layout_file=no_agent.txt",), ("agent",)),
    "layout_and_file": (("env.layout_file=map.txt", "env.layout=0.T\\n.X.\\n..."), ("layout",)),
    # bad transfer settings
    "source_not_a_checkpoint": (("env.layout_file=map.txt", "transfer=on", "transfer.source=map.txt"), ("map.txt",)),
    "source_agent_missing": (
        ("env.layout_file=map.txt", "transfer=on", "transfer.source=done", "transfer.source_agent=7"),
        ("7",),
    ),
    "source_is_a_directory_without_agents": (("transfer=on", "transfer.source=."), ("no agent_",)),
    "targets_out_of_team": (("env.layout_file=map.txt", "transfer=on", "transfer.targets=[5]"), ("targets",)),
    "exchange_every_zero": (("transfer.exchange_every=0",), ("transfer.exchange_every", ">= 1")),
    "freeze_beyond_the_network": (("transfer=on", "transfer.freeze=[9]"), ("transfer.freeze",)),
    "pretrain_steps_zero": (("transfer=on", "transfer.pretrain_steps=0"), ("transfer.pretrain_steps",)),
    # replicas and curriculum
    "replicas_zero": (("replicas.seeds=0",), ("replicas.seeds", ">= 1")),
    "replica_maps_on_a_layout": (("env.layout_file=map.txt", "replicas.maps=2"), ("replicas.maps=2", "layout")),
    "curriculum_stage_zero_steps": (
        ("transfer=on", "curriculum=grow", "curriculum.stages.0.steps=0"),
        ("curriculum.stages[0].steps",),
    ),
    # resume misuse
    "resume_shorter": (("resume=true", "hydra.run.dir=done", "total_steps=-1"), ("total_steps",)),
    "resume_shorter_budget": (("resume=true", "hydra.run.dir=done200", "total_steps=100"), ("total_steps=200",)),
    "resume_another_learner": (("resume=true", "hydra.run.dir=done", "agent=dqn"), ("resume=true", "agent")),
    "resume_missing_dir": (("resume=true", "hydra.run.dir=nowhere"), ("resume",)),
    "new_run_into_a_run": (("hydra.run.dir=done",), ("already holds a run",)),
    # bad hydra.run.dir
    "run_dir_under_a_file": (("hydra.run.dir=map.txt/run",), ("is a file",)),
    "run_dir_unwritable": (("hydra.run.dir=/proc/no_such_run",), ("/proc/no_such_run",)),
    "resume_another_games_state": (
        ("resume=true", "hydra.run.dir=mixed"),
        ("another run's", "env.factory=dqn_transfer.envs.lbf:parallel_env", "env.factory=null"),
    ),
    # settings that would be silently ignored, or meaningless
    "pettingzoo_without_a_factory": (("env=pettingzoo",), ("env=pettingzoo needs env.factory",)),
    "source_without_transfer": (("transfer.source=done",), ("transfer.source=done", "transfer=on")),
    "lbf_with_a_map_size": (("env=lbf", "env.size=10"), ("env.size=10", "treasure hunt", "lbf")),
    "lbf_with_a_mode": (("env=lbf", "mode=deliberative"), ("env.mode=deliberative", "lbf")),
    "buffer_below_a_batch": (
        ("agent.buffer_size=10", "agent.batch_size=64"),
        ("agent.buffer_size=10", "agent.batch_size=64"),
    ),
    "run_dir_empty": (("hydra.run.dir=",), ("hydra.run.dir is empty",)),
    "sweep_dir_empty": (("-m", "seed=0,1", "hydra.sweep.dir="), ("hydra.sweep.dir is empty",)),
    "sweep_dir_a_file": (("-m", "seed=0,1", "hydra.sweep.dir=map.txt"), ("map.txt is a file", "hydra.sweep.dir")),
    # an optional dependency not installed (MISSING below): the one line names the extra to install
    "joblib_launcher_missing": (("-m", "seed=0,1", "hydra/launcher=joblib"), ('pip install "dqn_transfer[sweep]"',)),
    "optuna_sweeper_missing": (("-m", "hydra/sweeper=optuna"), ('pip install "dqn_transfer[optuna]"',)),
    "tune_experiment_without_optuna": (
        ("experiment=tune/sarsa_best",),
        ("experiment=tune/sarsa_best", "hydra/sweeper=optuna", 'pip install "dqn_transfer[optuna]"'),
    ),
    "tune_sweep_without_optuna": (
        ("-m", "experiment=tune/double_dqn_none"),
        ("experiment=tune/double_dqn_none", 'pip install "dqn_transfer[optuna]"'),
    ),
    "submitit_launcher_missing": (
        ("-m", "seed=0,1", "hydra/launcher=submitit_slurm"),
        ('pip install "dqn_transfer[slurm]"',),
    ),
    "lbforaging_missing": (("env=lbf",), ("lbforaging", 'pip install "dqn_transfer[envs]"')),
    "mpe2_missing": (("env=mpe_spread",), ("mpe2", 'pip install "dqn_transfer[envs]"')),
    # unicode junk and malformed words
    "lr_emoji": (("agent.lr=⚡",), ("cannot read 'agent.lr=⚡'", "key=value")),
    "unicode_key": (("ñame=1",), ("ñame",)),
    "fullwidth_digits": (("env.size=６５",), ("env.size",)),
    "key_without_value": (("agent.lr",), ("agent.lr",)),
    "value_without_key": (("=5",), ("=5",)),
    "unclosed_list": (("agent.hidden=[64",), ("agent.hidden=[64",)),
}

# case -> the module its train.py process cannot import (the extras are installed where the tests run)
MISSING = {
    "joblib_launcher_missing": "hydra_plugins.hydra_joblib_launcher",
    "optuna_sweeper_missing": "hydra_plugins.hydra_optuna_sweeper",
    "tune_experiment_without_optuna": "hydra_plugins.hydra_optuna_sweeper",
    "tune_sweep_without_optuna": "hydra_plugins.hydra_optuna_sweeper",
    "submitit_launcher_missing": "hydra_plugins.hydra_submitit_launcher",
    "lbforaging_missing": "lbforaging",
    "mpe2_missing": "mpe2",
}
WITHOUT_MODULE = (
    "import sys; sys.modules[sys.argv.pop(1)] = None; sys.argv[0] = {train!r}; "
    "from dqn_transfer.cli.train import main; main()"
)


def train_words(name: str) -> list[str]:
    """The command of case ``name``: ``python train.py OVERRIDES``, without its module if one is MISSING."""
    overrides = [*CASES[name][0], "progress=false"]
    if name in MISSING:
        return [sys.executable, "-c", WITHOUT_MODULE.format(train=str(TRAIN_PY)), MISSING[name], *overrides]
    return [sys.executable, str(TRAIN_PY), *overrides]


def tree(path: Path) -> dict[str, str]:
    """Every file and directory under ``path`` with a digest of its content (directories: '')."""
    return {
        str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else ""
        for p in sorted(path.rglob("*"))
    }


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """The launch directory every case starts from: map files, three finished runs (two of the treasure hunt, one
    of LBF) and a treasure-hunt run holding the LBF run's resume state."""
    root = tmp_path_factory.mktemp("template")
    for name, text in FILES.items():
        (root / name).write_text(text)
    for name, steps, game in (
        ("done", 0, "env.layout_file=map.txt"),
        ("done200", 200, "env.layout_file=map.txt"),
        ("lbf", 0, "env=lbf"),
    ):
        subprocess.run(
            [sys.executable, str(TRAIN_PY), game, "agent=sarsa", f"total_steps={steps}"]
            + ["eval_every=100", "eval_episodes=1", "progress=false", f"hydra.run.dir={name}"],
            cwd=root,
            env=train_env(),
            capture_output=True,
            check=True,
            timeout=TRAIN_TIMEOUT,
        )
    # a treasure-hunt run whose resume state was copied from the LBF run
    shutil.copytree(root / "done", root / "mixed")
    shutil.copy(root / "lbf/checkpoints/training_state.safetensors", root / "mixed/checkpoints")
    return root


@pytest.fixture(scope="module")
def results(template, tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("cases")

    def run(name: str):
        cwd = root / name
        shutil.copytree(template, cwd)
        before = tree(cwd)
        proc = subprocess.run(
            train_words(name),
            cwd=cwd,
            env=train_env(),
            capture_output=True,
            text=True,
            timeout=TRAIN_TIMEOUT,
        )
        return proc, before, tree(cwd)

    with ThreadPoolExecutor(max_workers=2) as pool:
        return dict(zip(CASES, pool.map(run, CASES)))


def test_there_are_many_cases():
    assert len(CASES) >= 40


@pytest.mark.parametrize("name", list(CASES))
def test_a_bad_input_is_one_line_and_leaves_nothing(results, name):
    proc, before, after = results[name]
    lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
    assert proc.returncode != 0, lines
    assert len(lines) == 1, "\n".join(lines)
    assert lines[0].startswith("error: "), lines[0]
    for word in CASES[name][1]:
        assert word in lines[0], (word, lines[0])
    assert after == before, sorted(set(after) ^ set(before)) or "a file changed"
