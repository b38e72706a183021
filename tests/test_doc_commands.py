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

import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import IntervalSweep

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


def test_the_menu_lists_every_option_of_every_group():
    """docs/running.md's "Config groups (the menu)" equals the option files of each group (no ``m5``)."""
    from dqn_transfer.config.help import group_options

    readme = (ROOT / "docs" / "running.md").read_text(encoding="utf-8")
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
        ("docs/running.md", r"replicas\.maps=4 +# 5 seeds x 4 generated maps \(map seeds (\d+)\.\.(\d+)\)", []),
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


def test_the_help_line_the_docs_quote_is_printed():
    from dqn_transfer.config.help import help_text

    running = " ".join((ROOT / "docs" / "running.md").read_text(encoding="utf-8").split())
    quoted = re.search(r"\(`(agent\.lr .*?\(default [^)]*\))`\)", running)
    assert quoted, "docs/running.md no longer quotes a --help line (update this test)"
    printed = [" ".join(line.split()) for line in help_text("train.py").splitlines()]
    assert " ".join(quoted[1].split()) in printed


def test_each_timing_names_its_machine_and_date():
    """A figure in seconds or minutes in the README's and the guide's training and test paragraphs carries the
    machine and the date it was measured on, and the default run has one figure (it once had 97 s and 58 s)."""
    pages = [(ROOT / name).read_text(encoding="utf-8") for name in ("README.md", "docs/running.md", "docs/install.md")]
    assert not any("97 s" in page or "58 s" in page for page in pages)
    counts = [page.count("measured on this project's 2-core") for page in pages]
    assert all(count >= least for count, least in zip(counts, [1, 3, 1])), counts
    for doc in DOCS:
        for figure in re.finditer(r"\b\d+(?:\.\d+)? s\b[^\n]*\bhere\b", doc.read_text(encoding="utf-8")):
            raise AssertionError(f"{doc.name}: {figure[0]!r}: say which machine and when, not 'here'")


# --- the README: a front door that says what CI does ------------------------------------------------------

README_LIMIT = 15_000  # bytes (issue #33): what it is, the two commands, the headline command, where to read next


def test_the_readme_is_a_front_door():
    assert len((ROOT / "README.md").read_bytes()) <= README_LIMIT


def two_commands(doc: Path) -> list[str]:
    """The commands of the first bash block after ``doc``'s "## Two commands" heading (or, in docs/install.md,
    the page's first bash block), comments left out."""
    text = doc.read_text(encoding="utf-8")
    block = text[text.find("## Two commands") + 1 :].split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip() and not line.startswith("#")]


def test_the_readmes_two_commands_are_what_ci_runs():
    """The test command is ``.ci/run``'s, word for word but pip's ``-q``; the main job's installs the same way
    (the same venv and the same CPU-only torch first); docs/install.md repeats both as they are."""
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("python3 -m venv")]
    assert len(ci) == 1, "the CI script's command is one line starting with python3 -m venv"
    ci_command = ci[0].replace(" -q ", " ")
    install, test = two_commands(ROOT / "README.md")
    assert test == ci_command
    setup = ci_command.split(' && pip install -e ".[dev,docs]"')[0]
    assert install.startswith(setup + ' && pip install -e ".[') and install.endswith(" && python train.py")
    assert two_commands(ROOT / "docs" / "install.md") == [install, test]


# --- every training command the docs show composes (fast) ----------------------------------------------

# Lines that cannot compose as written, each for a stated reason (a part of a line identifies it). Every other
# `python train.py ...` line of a code block in README.md and docs/*.md must compose; an entry that no longer
# matches a line must go (test_the_allowed_lines_still_exist).
NOT_COMPOSED = {
    # placeholders the reader fills in
    "env.factory=PACKAGE.MODULE:CALLABLE": "the usage line of env=pettingzoo: a placeholder factory and key",
}
# COMMON="..." in a block, used as $COMMON by its commands
SHELL_VARIABLE = re.compile(r"""^([A-Z_]+)=("[^"]*"|'[^']*'|\S*)$""")


def train_lines() -> list[tuple[str, str]]:
    """(file:line, command) for every ``python train.py ...`` line of a fenced code block in the docs,
    continuation lines joined, and the block's own shell variables (``COMMON="..."``) put in."""
    found = []
    for doc in DOCS:
        lines, fenced, variables = doc.read_text(encoding="utf-8").splitlines(), False, {}
        number = 0
        while number < len(lines):
            line = lines[number].strip()
            number += 1
            if line.startswith("```"):
                fenced, variables = not fenced, {}
                continue
            if fenced and (assignment := SHELL_VARIABLE.match(line)):
                variables[assignment[1]] = " ".join(shlex.split(assignment[2]))
            if not (fenced and line.startswith("python train.py")):
                continue
            where = f"{doc.relative_to(ROOT)}:{number}"
            while line.endswith("\\") and number < len(lines):
                line = line[:-1] + " " + lines[number].strip()
                number += 1
            for name, value in variables.items():
                line = line.replace(f"${name}", value)
            found.append((where, line))
    return found


def package_overrides(command: str) -> list[str]:
    """The overrides of ``command`` that the package's config composes: flags (``-m``, ``--help``) and Hydra's
    own settings (``hydra/launcher=...``, ``hydra.run.dir=...``: Hydra's config, checked by Hydra at launch)
    left out, a sweep (``a=1,2``, ``range(10)``) as its first value and an Optuna search space
    (``interval(a, b)``) as its start."""
    words = [
        word
        for word in shlex.split(command, comments=True)[2:]
        if not word.startswith("-") and not word.lstrip("+~").startswith("hydra")
    ]
    overrides = []
    for override in OverridesParser.create().parse_overrides(words):
        sweep = override.value()
        if isinstance(sweep, IntervalSweep):
            value: str | None = str(sweep.start)
        else:
            value = next(override.sweep_string_iterator()) if override.is_sweep_override() else None
        overrides.append(override.input_line if value is None else f"{override.get_key_element()}={value}")
    return overrides


def test_the_train_lines_are_found():
    """A regex gone wrong would make the next test check nothing: these lines are in the docs today."""
    lines = [command for _, command in train_lines()]
    assert len(lines) > 50
    assert "python train.py agent=sarsa mode=cooperative           # the study's learner" in lines
    assert any(
        line.startswith("python train.py -m hydra/launcher=submitit_slurm") and "\\" not in line for line in lines
    )
    assert package_overrides(
        "python train.py -m 'seed=range(10)' mode=a,b hydra/launcher=joblib hydra.x=<y> "
        "'agent.lr=tag(log, interval(1e-4, 1))' --help # x"
    ) == ["seed=0", "mode=a", "agent.lr=0.0001"]
    assert any("agent.engine=numpy" in line and "$COMMON" not in line for line in lines)  # the block's variable


def documented_overrides() -> dict[tuple[str, ...], str]:
    """The distinct override lists of the docs' training commands (NOT_COMPOSED's left out), each with the first
    file:line that shows it."""
    found: dict[tuple[str, ...], str] = {}
    for where, command in train_lines():
        if not any(part in command for part in NOT_COMPOSED):
            found.setdefault(tuple(package_overrides(command)), where)
    return found


def test_every_train_line_in_the_docs_passes_the_command_lines_check():
    """Each ``python train.py ...`` line of README.md and docs/*.md passes the check ``python train.py`` makes
    before Hydra: every key in the schema, every group option a file, every value of its key's type."""
    from dqn_transfer.config import ConfigError
    from dqn_transfer.config.overrides import check_overrides

    failed = []
    for overrides, where in documented_overrides().items():
        try:
            check_overrides(list(overrides))
        except ConfigError as err:
            failed.append(f"{where}: {' '.join(overrides)}\n    {err}")
    assert not failed, "these documented commands are refused:\n" + "\n".join(failed)


@pytest.mark.slow  # ~0.1 s of Hydra composition per distinct command, 66 of them today
def test_every_train_line_in_the_docs_composes():
    """... and composes with Hydra against the package's config into a valid TrainConfig."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from omegaconf import OmegaConf

    from dqn_transfer.config.schema import CONFIG_DIR, register_configs

    register_configs()
    failed = []
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        for overrides, where in documented_overrides().items():
            try:
                OmegaConf.to_object(hydra_compose(config_name="config", overrides=list(overrides)))
            except Exception as err:  # any failure is the docs' to fix: say where and why
                failed.append(f"{where}: {' '.join(overrides)}\n    {type(err).__name__}: {str(err).splitlines()[0]}")
    assert not failed, "these documented commands do not compose:\n" + "\n".join(failed)


def test_the_allowed_lines_still_exist():
    lines = [command for _, command in train_lines()]
    assert [part for part in NOT_COMPOSED if not any(part in line for line in lines)] == []


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


def readme_command(start: str) -> list[str]:
    """The words of the README's code line that starts with ``start``, its comment left out."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    return shlex.split(next(line for line in lines if line.startswith(start)), comments=True)


@pytest.mark.slow
def test_the_readmes_export_and_warm_start_work_from_a_fresh_folder(tmp_path):
    """The README's export line, then its warm-start line, after a short run, in a folder without ``shared/``:
    the export makes it, and the warm-started team starts agent i from exported agent i, so its step-0
    evaluation is the exported team's last one (issue #31: every agent started from agent 0, team return
    61 against the team's 194); the warm start's first line names its directory."""
    export = readme_command("dqn-transfer-ckpt export RUN shared/team")
    warm = readme_command("python train.py transfer=on transfer.source=shared/team")
    quiet = ["eval_episodes=2", "progress=false"]

    def run(argv: list[str]) -> str:
        done = subprocess.run(
            runnable(tuple(argv)), cwd=tmp_path, env=child_env(), capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, f"{' '.join(argv)}\n{done.stderr[-3000:]}"
        return done.stdout + done.stderr

    run(["python", "train.py", "total_steps=2000", "eval_every=1000", *quiet, "hydra.run.dir=team"])
    run([word.replace("RUN", "team") for word in export])
    assert sorted(p.name for p in (tmp_path / "shared").iterdir()) == ["team"]
    said = run([*warm, "total_steps=1", *quiet, "hydra.run.dir=warm"])
    assert said.splitlines()[0].endswith(f"run directory: {tmp_path / 'warm'}"), said

    def evaluations(run_dir: str) -> list[dict]:
        lines = (tmp_path / run_dir / "metrics.jsonl").read_text().splitlines()
        keys = ("team_return", "success_rate", "episode_length", "agent_returns")
        return [{key: record[key] for key in keys} for record in map(json.loads, lines)]

    last = evaluations("team")[-1]
    assert last["success_rate"] == 1.0  # a team that solves the map: agent 0's way alone does not (61, not 194)
    assert evaluations("warm")[0] == last
