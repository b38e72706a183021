"""The docs name only what exists: every backticked ``dqn_transfer.…`` name in README.md and docs/*.md
imports (a module, or an attribute of one), and every backticked ``dqn_transfer/…`` or ``conf/…`` path is a file
or folder of the repository, so a rename or a move that forgets the docs fails here."""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # mypy's own dependency there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])

CODE_SPAN = re.compile(r"`([^`\n]+)`")
DOTTED = re.compile(r"(?<![\w./-])dqn_transfer(?:\.(?:[A-Za-z_]\w*|<[\w|]+>))+")  # <a|b>: one per alternative
PATH = re.compile(r"(?<![\w./-])(?:dqn_transfer|conf)/[\w./{},-]*")  # {a,b}: one name per alternative
FROM_IMPORT = re.compile(r"^\s*from\s+([\w.]+)\s+import\s+([\w\s,]+?)\s*(?:#.*)?$")
ALTERNATIVES = re.compile(r"\{([^{}]*)\}|<([^<>]*)>")

# Names that other branches' docs still carry and fix in their own rewrite (empty this after the merge).
PENDING: set[str] = set()


def named_in_docs() -> list[tuple[str, str]]:
    """(where, name) for every dotted name and path in the docs' code: inline code spans, and the lines
    of fenced code blocks, where ``from dqn_transfer.x import a, b`` names ``dqn_transfer.x.a`` and
    ``dqn_transfer.x.b``; in order of appearance."""
    found = []
    for doc in DOCS:
        fenced = False
        for number, line in enumerate(doc.read_text(encoding="utf-8").splitlines(), start=1):
            if line.lstrip().startswith("```"):
                fenced = not fenced
                continue
            where = f"{doc.relative_to(ROOT)}:{number}"
            for code in [line] if fenced else CODE_SPAN.findall(line):
                names = [
                    name for found_name in DOTTED.findall(code) + PATH.findall(code) for name in expand(found_name)
                ]
                imported = FROM_IMPORT.search(code)
                if imported and imported.group(1).startswith("dqn_transfer"):
                    names += [f"{imported.group(1)}.{name.split()[0]}" for name in imported.group(2).split(",")]
                found += [(where, name.rstrip(".")) for name in names]
    return found


def expand(name: str) -> list[str]:
    """``a/m{2,3}.yaml`` as the shell reads it (``a/m2.yaml``, ``a/m3.yaml``), and ``a.<b|c>`` as the
    docs' usage lines mean it (``a.b``, ``a.c``)."""
    match = ALTERNATIVES.search(name)
    if match is None:
        return [name]
    head, tail = name[: match.start()], name[match.end() :]
    choices = match.group(1).split(",") if match.group(1) is not None else match.group(2).split("|")
    return [expanded for choice in choices for expanded in expand(head + choice + tail)]


def is_module(dotted: str) -> bool:
    """Whether ``dotted`` is a module or package of this repository's files (not of whatever else is on
    the path: an older copy of the package installed elsewhere may still hold a module that moved)."""
    base = ROOT.joinpath(*dotted.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def resolves(name: str) -> bool:
    """Whether ``name`` is an existing path of the repository (``dqn_transfer/…``), or a module of it,
    or an attribute chain under the longest module prefix of it."""
    if "/" in name:
        return (ROOT / name).exists()
    parts = name.split(".")
    if is_module(name):
        return True  # without importing it (some import torch)
    for end in range(len(parts) - 1, 0, -1):
        if not is_module(".".join(parts[:end])):
            continue
        obj = importlib.import_module(".".join(parts[:end]))
        for attr in parts[end:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_the_docs_name_something():
    """The extraction finds what it should (a regex gone wrong would make the next test pass on nothing)."""
    names = {name for _, name in named_in_docs()}
    assert "dqn_transfer/config/schema.py" in names
    assert "conf/config.yaml" in names
    assert any(name.startswith("dqn_transfer.") for name in names)
    assert "dqn_transfer.sharing.team.load_team" in names  # from a fenced example's import line


def test_resolves_tells_what_exists_from_what_does_not():
    assert resolves("dqn_transfer.storage.checkpoint")
    assert resolves("dqn_transfer.envs.maps.optimal_team_return")
    assert resolves("dqn_transfer/storage/run_dir.py") and resolves("conf/env/study/m2.yaml")
    assert not resolves("dqn_transfer/conf/")  # the config groups before they moved to the repository's root
    assert expand("conf/env/study/m{2,3}.yaml") == ["conf/env/study/m2.yaml", "conf/env/study/m3.yaml"]
    assert expand("dqn_transfer.cli.<train|play>") == ["dqn_transfer.cli.train", "dqn_transfer.cli.play"]
    assert not resolves("dqn_transfer.checkpoint")  # the module before it moved to storage/
    assert not resolves("dqn_transfer.envs.maps.no_such_function")
    assert not resolves("dqn_transfer/run_dir.py")


def test_every_name_in_the_docs_exists():
    missing = [f"{where}: {name}" for where, name in named_in_docs() if name not in PENDING and not resolves(name)]
    assert not missing, "the docs name what does not exist:\n" + "\n".join(missing)


def test_the_pending_names_are_still_missing():
    """An allowed name that resolves (or no longer appears) must leave PENDING, so it empties after the merge."""
    named = {name for _, name in named_in_docs()}
    assert not {name for name in PENDING if resolves(name) or name not in named}


def test_the_readme_names_every_console_script_and_no_other():
    """The README's console scripts are ``[project.scripts]`` of pyproject.toml, all of them (issue #31: it missed
    ``dqn-transfer-export``)."""
    with open(ROOT / "pyproject.toml", "rb") as file:
        scripts = set(tomllib.load(file)["project"]["scripts"])
    named = set(re.findall(r"(?<![\w-])dqn-transfer-[a-z]+", (ROOT / "README.md").read_text(encoding="utf-8")))
    assert named == scripts
