"""The docs cannot drift: their marked commands run, and the facts they state that code can check hold.

A fenced code block right after an HTML comment ``<!-- doc-test[ skip=N,M]: OVERRIDES -->`` is run by
this test: each command line of a ``bash`` block (``python train.py ...``, ``dqn-transfer-<x> ...``),
with OVERRIDES appended (small step counts), in a fresh working directory, must exit 0; ``skip`` names
the block's command lines (counted from 1) that need something the test does not have (a map file, a
colleague's checkpoint). ``<!-- doc-test: python[ replace=A:B] -->`` runs a ``python`` block as a script
(with each ``A`` replaced by ``B``, to shorten it). The facts (the README's menu of config groups,
docs/sweeps.md's map seeds and experiment table, the ``--help`` line the README quotes) are checked
without starting a process.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
MARKER = re.compile(r"^<!-- doc-test(?: skip=(?P<skip>[\d,]+))?: (?P<args>.*?) -->$")


@dataclass(frozen=True)
class DocCommand:
    where: str  # file:line of the command
    argv: tuple[str, ...]  # as the user types it, the marker's overrides appended


@dataclass(frozen=True)
class DocScript:
    where: str  # file:line of the block
    source: str


def marked_blocks() -> list[tuple[str, re.Match[str], str, list[tuple[int, str]]]]:
    """(where, marker, language, [(line number, line)]) for every code block after a doc-test marker."""
    found = []
    for doc in DOCS:
        lines = doc.read_text(encoding="utf-8").splitlines()
        for number, line in enumerate(lines):
            marker = MARKER.match(line.strip())
            if marker is None:
                continue
            fence = lines[number + 1]
            assert fence.startswith("```"), f"{doc.name}:{number + 1}: a doc-test marker must precede a code block"
            body = []
            for offset, text in enumerate(lines[number + 2 :], start=number + 3):
                if text.startswith("```"):
                    break
                body.append((offset, text))
            found.append((f"{doc.relative_to(ROOT)}:{number + 1}", marker, fence[3:].strip(), body))
    return found


def doc_commands() -> list[DocCommand]:
    """The shell commands of the marked ``bash`` blocks, continuation lines joined."""
    commands = []
    for where, marker, language, body in marked_blocks():
        if language != "bash":
            continue
        skip = {int(n) for n in (marker["skip"] or "").split(",") if n}
        joined: list[tuple[int, str]] = []
        for number, text in body:
            if joined and joined[-1][1].endswith("\\"):
                joined[-1] = (joined[-1][0], joined[-1][1][:-1] + " " + text.strip())
            elif text.strip():
                joined.append((number, text))
        for index, (number, text) in enumerate(joined, start=1):
            if index in skip:
                continue
            argv = shlex.split(text, comments=True) + shlex.split(marker["args"])
            commands.append(DocCommand(f"{where.split(':')[0]}:{number}", tuple(argv)))
    return commands


def doc_scripts() -> list[DocScript]:
    scripts = []
    for where, marker, language, body in marked_blocks():
        if language != "python":
            continue
        args = marker["args"].split()
        assert args[0] == "python", f"{where}: a python block's marker starts with 'python'"
        source = "\n".join(text for _, text in body) + "\n"
        for option in args[1:]:
            old, new = option.removeprefix("replace=").split(":")
            assert old in source, f"{where}: {old!r} is not in the block"
            source = source.replace(old, new)
        scripts.append(DocScript(where, source))
    return scripts


def runnable(argv: tuple[str, ...]) -> list[str]:
    """The command with this Python: ``python train.py`` and the console scripts by module."""
    if argv[:2] == ("python", "train.py"):
        return [sys.executable, str(ROOT / "train.py"), *argv[2:]]
    if argv[0].startswith("dqn-transfer-"):
        return [sys.executable, "-m", f"dqn_transfer.cli.{argv[0].removeprefix('dqn-transfer-')}", *argv[1:]]
    raise AssertionError(f"the doc test does not know how to run {argv[0]!r}")


def child_env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}


# --- the mechanism itself (fast) ------------------------------------------------------------------------


def test_the_marked_blocks_are_found():
    """A regex gone wrong would make the slow tests run nothing; these are the blocks marked today."""
    commands = [" ".join(c.argv) for c in doc_commands()]
    assert any(c.startswith("python train.py agent=sarsa mode=cooperative total_steps=100") for c in commands)
    assert not any("layout_file=my_map.txt" in c for c in commands)  # skip=4: no such file here
    assert any("transfer=on" in c and "transfer.pretrain_steps=100" in c for c in commands)
    assert any(c.startswith("python train.py replicas.seeds=5 replicas.maps=4 env=complex") for c in commands)
    assert all("#" not in c for c in commands)  # the comments are stripped
    assert [s.where.split(":")[0] for s in doc_scripts()] == ["docs/other_libraries.md"]
    assert "total_timesteps=300" in doc_scripts()[0].source


def test_every_command_is_runnable():
    for command in doc_commands():
        runnable(command.argv)


# --- the facts the docs state (fast) --------------------------------------------------------------------


def test_the_readme_menu_lists_every_option_of_every_group():
    """README.md's "Config groups (the menu)" equals the option files of each group (no ``m5``)."""
    from dqn_transfer.config.help import group_options

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    menu = readme[readme.index("Config groups (the menu):") :].split("(and `condition=`")[0]
    listed = dict(re.findall(r"`(\w+)=([\w/|]+)`", menu))
    assert set(listed) == {"env", "mode", "agent", "transfer", "curriculum", "experiment"}
    for group, options in listed.items():
        assert sorted(options.split("|")) == group_options(group), group
    assert "`condition=`" in readme  # the one group the menu names without its options


def compose(*overrides: str):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from omegaconf import OmegaConf

    from dqn_transfer.config.schema import CONFIG_DIR, register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return OmegaConf.to_object(hydra_compose(config_name="config", overrides=list(overrides)))


@pytest.mark.parametrize(
    ("doc", "pattern", "overrides"),
    [
        ("docs/sweeps.md", r"env=complex +# 5 seeds x map seeds (\d+)\.\.(\d+)", ["env=complex"]),
        ("README.md", r"replicas\.maps=4 +# 5 seeds x 4 generated maps \(map seeds (\d+)\.\.(\d+)\)", []),
    ],
)
def test_the_map_seeds_the_docs_state_are_the_replicas(doc, pattern, overrides):
    from dqn_transfer.training.plan import plan_run

    stated = re.search(pattern, (ROOT / doc).read_text(encoding="utf-8"))
    assert stated, f"{doc} no longer states the map seeds (update this test)"
    plan = plan_run(compose("replicas.seeds=5", "replicas.maps=4", *overrides))
    map_seeds = sorted({replica.config.env.map_seed for replica in plan.replicas})
    assert map_seeds == list(range(int(stated[1]), int(stated[2]) + 1))


def test_the_sweeps_table_counts_the_jobs_and_runs():
    """docs/sweeps.md's first-edition table: ``jobs x runs`` is each experiment's sweep and replicas."""
    from dqn_transfer.experiments.sweeps import count_jobs

    text = (ROOT / "docs" / "sweeps.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \|.*\| (\d+) x (\d+) \|$", text, flags=re.M)
    assert len(rows) == 5
    for name, jobs, runs in rows:
        config = compose(f"experiment={name}")
        assert count_jobs(name, []) == int(jobs), name
        assert config.replicas.seeds * config.replicas.maps == int(runs), name


def test_the_second_editions_table_counts_the_jobs():
    """docs/sweeps.md's second-edition table: ``jobs`` is each v2 experiment's sweep."""
    from dqn_transfer.config.help import group_options
    from dqn_transfer.experiments.sweeps import count_jobs

    text = (ROOT / "docs" / "sweeps.md").read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\| `(v2/\w+)` \|.*\| (\d+) \|$", text, flags=re.M))
    assert sorted(rows) == [name for name in group_options("experiment") if name.startswith("v2/")]
    for name, jobs in rows.items():
        assert count_jobs(name, []) == int(jobs), name


def test_the_help_line_the_readme_quotes_is_printed():
    from dqn_transfer.config.help import help_text

    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    quoted = re.search(r"\(`(agent\.lr .*?\(default [^)]*\))`\)", readme)
    assert quoted, "the README no longer quotes a --help line (update this test)"
    printed = [" ".join(line.split()) for line in help_text("train.py").splitlines()]
    assert " ".join(quoted[1].split()) in printed


def test_each_timing_names_its_machine_and_date():
    """A figure in seconds or minutes in the README's training and test paragraphs carries the machine
    and the date it was measured on, and the default run has one figure (it once had 97 s and 58 s)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "97 s" not in readme and "58 s" not in readme
    assert readme.count("measured on this project's 2-core") >= 4
    for doc in DOCS:
        for figure in re.finditer(r"\b\d+(?:\.\d+)? s\b[^\n]*\bhere\b", doc.read_text(encoding="utf-8")):
            raise AssertionError(f"{doc.name}: {figure[0]!r}: say which machine and when, not 'here'")


# --- the commands and scripts themselves (processes: slow) ----------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("command", doc_commands(), ids=lambda c: c.where)
def test_doc_command_runs(command, tmp_path):
    result = subprocess.run(
        runnable(command.argv), cwd=tmp_path, env=child_env(), capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, f"{command.where}: {' '.join(command.argv)}\n{result.stderr[-3000:]}"


@pytest.mark.slow
@pytest.mark.parametrize("script", doc_scripts(), ids=lambda s: s.where)
def test_doc_script_runs(script, tmp_path):
    (tmp_path / "example.py").write_text(script.source)
    result = subprocess.run(
        [sys.executable, "example.py"], cwd=tmp_path, env=child_env(), capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, f"{script.where}\n{result.stderr[-3000:]}"
    assert "greedy first action:" in result.stdout
