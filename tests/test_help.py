"""``python train.py --help``: the config menu and every schema key with its description and default."""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import TRAIN_PY, train_env

from dqn_transfer.config import TrainConfig
from dqn_transfer.config.help import config_groups, first_sentence, help_text
from dqn_transfer.documented import describe, documented


def schema_fields(schema: type, prefix: str = "") -> dict[str, dataclasses.Field]:
    """Every leaf field of the schema by dotted key, walked here with dataclasses alone."""
    found = {}
    for f in dataclasses.fields(schema):
        if dataclasses.is_dataclass(f.default_factory):  # a group: env, agent, transfer, replicas
            found.update(schema_fields(f.default_factory, f"{prefix}{f.name}."))
        else:
            found[prefix + f.name] = f
    return found


def key_line(page: str, key: str) -> str:
    lines = [line for line in page.splitlines() if re.match(rf"\s+{re.escape(key)}\s", line)]
    assert len(lines) == 1, f"{key}: {lines}"
    return lines[0]


def test_help_names_every_schema_key_with_its_own_description():
    page = help_text("python train.py")
    keys = schema_fields(TrainConfig)
    assert len(keys) == 79 and {
        "agent.lr",
        "agent.engine",
        "agent.mixer",
        "env.size",
        "env.factory",
        "env.contention",
        "env.kwargs",
        "env.fixed_start",
        "transfer.source",
        "transfer.source_task",
        "transfer.chest_aware",
        "transfer.source_map_shift",
        "transfer.confidence_weight",
        "transfer.advice_budget",
        "replicas.seeds",
        "threads",
        "eval_pictures",
        "logger",
    } <= set(keys)
    for key, f in keys.items():
        line = key_line(page, key)
        assert f.metadata["help"] in line, line


@pytest.mark.parametrize(
    "key, description, default",
    [
        ("agent.lr", "Adam step size (DQN) or alpha (tabular)", "0.001"),
        ("env.size", "grid side n", "6"),
        ("env.num_traps", "traps; null: k", "null"),
        ("agent.hidden", "MLP hidden sizes", "[64,64]"),
        ("env.mode", "how `treasures` is kept", "competitive"),
        ("agent.share_parameters", "parameter-sharing baseline", "false"),
        ("total_steps", "joint env steps", "20000"),
    ],
)
def test_a_key_line_reads_key_description_default(key, description, default):
    line = key_line(help_text("python train.py"), key)
    assert re.fullmatch(
        rf"\s+{re.escape(key)}\s+.*{re.escape(description)}.*\s\s\(default {re.escape(default)}\)", line
    )


def test_help_shows_the_menu_with_its_defaults():
    page = help_text("dqn-transfer-train")
    assert page.startswith("usage: dqn-transfer-train [group=option ...] [key=value ...]")
    menu = page[page.index("Config groups") : page.index("Keys")]
    for group, options, default in [
        ("agent", ["double_dqn", "dqn", "qlearning", "sarsa"], "double_dqn"),
        ("env", ["complex", "simple"], "simple"),
        ("mode", ["competitive", "cooperative", "deliberative"], "competitive"),
        ("transfer", ["off", "on"], "off"),
    ]:
        assert f"  {group}:\n" in menu
        for option in options:
            assert re.search(rf"^   {'[*]' if option == default else ' '}{option}\s+\S", menu, re.M), option
    assert re.search(r"^   \*simple\s+A small map: 6x6, 2 chests, 2 traps, 2 agents$", menu, re.M)


def test_the_groups_are_the_config_folders_not_pythons_bytecode_cache(tmp_path):
    """conf/ is a Python package (conf/__init__.py), so importing it may leave a __pycache__ folder there: the
    menu and the overrides' checks do not take it for a group, as Hydra does not."""
    for folder in ["agent", "env/study", "__pycache__"]:
        (tmp_path / folder).mkdir(parents=True)
    (tmp_path / "__init__.py").write_text("")
    (tmp_path / "config.yaml").write_text("defaults: []\n")
    assert config_groups(tmp_path) == ("agent", "env")


def test_a_schema_key_without_a_description_is_refused():
    with pytest.raises(ValueError, match="needs its description"):
        documented(1)

    @dataclasses.dataclass
    class Undocumented:
        size: int = 6

    with pytest.raises(TypeError, match="Undocumented.size has no description"):
        describe(Undocumented)


@pytest.mark.slow
def test_train_py_and_the_console_script_print_it_without_running(tmp_path):
    script = shutil.which("dqn-transfer-train", path=str(Path(sys.executable).parent))
    assert script, "the console script is installed with the package (pip install -e .)"
    for command, program in [
        ([sys.executable, str(TRAIN_PY), "--help"], f"python {TRAIN_PY}"),
        ([script, "agent=sarsa", "--help"], "dqn-transfer-train"),
    ]:
        proc = subprocess.run(command, cwd=tmp_path, env=train_env(), capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.startswith(f"usage: {program} ")
        assert re.search(
            r"^\s+agent\.lr\s+Adam step size \(DQN\) or alpha \(tabular\)\s+\(default 0\.001\)$", proc.stdout, re.M
        )
        assert "== Config ==" not in proc.stdout  # not Hydra's generic page
    assert list(tmp_path.iterdir()) == []  # no run started, no outputs/


@pytest.mark.slow
def test_help_read_by_a_reader_that_stops_early_exits_quietly(tmp_path):
    """``python train.py --help | head -1``: the reader closes the pipe after one line of the 23 KB menu; the
    writer ends with exit code 0 and says nothing (it was a BrokenPipeError traceback)."""
    reader = subprocess.Popen(["head", "-1"], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
    assert reader.stdin is not None
    writer = subprocess.run(
        [sys.executable, str(TRAIN_PY), "--help"],
        cwd=tmp_path,
        env=train_env(),
        stdout=reader.stdin,
        stderr=subprocess.PIPE,
        text=True,
        timeout=120,
    )
    reader.stdin.close()
    reader.wait()
    assert (writer.returncode, writer.stderr) == (0, "")


def test_an_option_summary_is_its_whole_first_sentence():
    """An abbreviation's period ("et al.") does not end the sentence (the menu once read ``double_dqn
    Double DQN (van Hasselt et al``); a sentence running onto the next comment line is shown whole."""
    menu = help_text("python train.py")
    assert re.search(
        r"^   \*double_dqn\s+Double DQN \(van Hasselt et al\. 2016\): the online net picks argmax a', "
        r"the target net values it$",
        menu,
        re.M,
    )
    assert re.search(r"^    dqn\s+DQN \(Mnih et al\. 2015\): MLP Q-network, .*, Adam$", menu, re.M)
    assert re.search(r"^    curriculum\s+Claim 3's curriculum question .* env steps\?$", menu, re.M)
    assert first_sentence("Warm start (e.g. Optuna). Then more.") == "Warm start (e.g. Optuna)"
    assert first_sentence("One sentence\nover two lines.") == "One sentence\nover two lines"
