"""``python train.py --help``: the config menu and every key with its description and default.

Both come from where they are defined, never from a copy: the groups and their options from the
YAML files under ``conf/`` (an option's description is its file's first comment line, its default
the one ``conf/config.yaml`` picks), the keys from the schema dataclasses (each field's
:func:`~dqn_transfer.documented.documented` description and default).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from dqn_transfer.config.schema import CONFIG_DIR, TrainConfig
from dqn_transfer.documented import describe, format_default

ROOT_CONFIG = "config.yaml"


def config_groups(config_dir: Path = CONFIG_DIR) -> tuple[str, ...]:
    """The config groups (``agent``, ``env``, ...): the folders under ``conf/``."""
    # not the bytecode cache of conf/__init__.py (the package dqn_transfer.conf), which Hydra skips too
    return tuple(sorted(p.name for p in config_dir.iterdir() if p.is_dir() and p.name != "__pycache__"))


def group_options(group: str, config_dir: Path = CONFIG_DIR) -> list[str]:
    """The options of a group: its YAML files' names, with their folder below the group (``study/m2``)."""
    root = config_dir / group
    return sorted(p.relative_to(root).with_suffix("").as_posix() for p in root.rglob("*.yaml"))


def option_values(group: str, option: str, config_dir: Path = CONFIG_DIR) -> dict[str, Any]:
    """The keys an option's file sets (``option_values("env", "study/m4")``)."""
    return yaml.safe_load((config_dir / group / f"{option}.yaml").read_text()) or {}


def default_options(config_dir: Path = CONFIG_DIR) -> dict[str, str | None]:
    """The option ``conf/config.yaml``'s defaults list picks for each group (None: none)."""
    defaults = yaml.safe_load((config_dir / ROOT_CONFIG).read_text())["defaults"]
    return {group: option for entry in defaults if isinstance(entry, dict) for group, option in entry.items()}


# Words whose period does not end a sentence ("van Hasselt et al. 2016", "e.g. Optuna").
ABBREVIATIONS = ("al", "e.g", "i.e", "etc", "cf", "vs", "approx", "Fig", "Eq")
# A period, question or exclamation mark that may end a sentence: followed by a space and what may start one.
SENTENCE_END = re.compile(r"[.?!](?=\s+[A-Z`\"'(\[])")


def first_sentence(text: str) -> str:
    """``text``'s first sentence, without its final period: it ends at a period (or ``?``, ``!``) followed
    by a space and a capital (or a quote, a bracket), except after an abbreviation such as "et al."."""
    for match in SENTENCE_END.finditer(text):
        if match.group() != ".":
            return text[: match.end()]
        word = text[: match.start()].rsplit(None, 1)[-1].lstrip("(")
        if word not in ABBREVIATIONS:
            return text[: match.start()]
    return text.rstrip().removesuffix(".")


def option_summary(path: Path) -> str:
    """The first sentence of an option file's leading comment (what it is, possibly over several
    lines), without Hydra's ``@package`` header."""
    comment: list[str] = []
    for line in path.read_text().splitlines():
        text = line.strip()
        if not text.startswith("#"):
            break
        text = text.lstrip("#").strip()
        if text.startswith("@package"):
            continue
        if not text:
            if comment:
                break
            continue
        comment.append(text)
    return first_sentence(" ".join(comment))


def help_text(program: str, config_dir: Path = CONFIG_DIR) -> str:
    """The whole ``--help`` page for ``program`` (the command as the user typed it)."""
    lines = [
        f"usage: {program} [group=option ...] [key=value ...]",
        f"       {program} -m [group=a,b ...] [key=x,y ...]     (a Hydra multirun sweep)",
        "",
        "Train a team of agents on the treasure hunt; the run lands in outputs/runs/<date>/<time>/",
        "(or hydra.run.dir=PATH). Docs: README.md and docs/.",
        "",
        "Config groups (group=option; * marks the default):",
    ]
    defaults = default_options(config_dir)
    for group in config_groups(config_dir):
        lines.append(f"  {group}:")
        options = group_options(group, config_dir)
        width = max(map(len, options))
        for option in options:
            mark = "*" if defaults.get(group) == option else " "
            summary = option_summary(config_dir / group / f"{option}.yaml")
            lines.append(f"   {mark}{option:<{width}}  {summary}".rstrip())
    keys = describe(TrainConfig)
    width = max(len(k.key) for k in keys)
    lines += ["", "Keys (key  description  (schema default; the groups above may set another)):"]
    lines += [f"  {k.key:<{width}}  {k.doc}  (default {format_default(k.default)})" for k in keys]
    lines += [
        "",
        "Hydra: --cfg job prints the composed config without running, --hydra-help lists Hydra's own flags,",
        "hydra.run.dir=PATH names the run directory, resume=true hydra.run.dir=PATH continues a run.",
    ]
    return "\n".join(lines)
