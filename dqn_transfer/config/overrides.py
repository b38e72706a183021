"""The command line's overrides, checked against the schema before Hydra composes anything.

A key outside the schema (``+`` appends included), an option no config group has, a value the key's
type cannot hold (``agent.lr=fast``) or a word that is no override at all ends in one ``ConfigError``
line naming the nearest valid key or the expected type, where Hydra would print four to six lines or,
for an appended key, store it silently.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import importlib.util
import re
import sys
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from dqn_transfer.config.help import config_groups, group_options, option_values
from dqn_transfer.config.schema import CONFIG_DIR, SB3_NAMES, ConfigError, StageConfig, TrainConfig
from dqn_transfer.documented import describe
from dqn_transfer.enums import EXTRA_MODULES, HYDRA_PLUGINS

# An override of one curriculum stage's key, e.g. curriculum.stages.0.steps (group 1: the stage's key).
STAGE_ELEMENT = re.compile(r"curriculum\.stages\.\d+\.([^.]+)(\..*)?")
STAGE_KEYS = [f.name for f in dataclasses.fields(StageConfig)]
# Other libraries' names for our agent keys (SB3's, and CleanRL's dqn.py where they differ), so a user
# who types the name they know is pointed at ours.
AGENT_ALIASES = {
    **{sb3: ours for ours, sb3 in SB3_NAMES.items()},
    "net_arch": "hidden",
    "target_network_frequency": "target_update",
    "train_frequency": "train_freq",
    "start_e": "eps_start",
    "end_e": "eps_end",
}


def check_overrides(argv: list[str]) -> None:
    """Refuse a key outside the schema (``+`` appends included) or an option no group has, naming the
    nearest valid one, before Hydra turns it into a multi-line error or silently stores it."""
    check_hydra_modes(argv)
    parser = OverridesParser.create()
    overrides = []
    for word in override_words(argv):  # malformed (agent.lr, =5, unicode junk): one line, not Hydra's four
        try:
            overrides += parser.parse_overrides([word])
        except HydraException:
            raise ConfigError(
                f"cannot read '{word}': an override is key=value (value: a number, true/false, null, a word "
                "or 'quoted text', a [list] or {mapping}; see --help)"
            ) from None
    check_plugins(overrides)
    groups = config_groups()
    keys = [k.key for k in describe(TrainConfig)]
    types = schema_types(TrainConfig)
    for override in overrides:
        key = override.key_or_group
        if key in groups:
            check_group_option(key, override)
        elif (stage := STAGE_ELEMENT.fullmatch(key)) and stage.group(1) not in STAGE_KEYS:
            raise ConfigError(
                f"unknown curriculum stage key '{stage.group(1)}' in '{override.input_line}' "
                f"(a stage has {', '.join(STAGE_KEYS)})"
            )
        elif key in types:
            check_value_type(override, types[key])
        elif not key.startswith("hydra") and key not in keys and not any(key.startswith(f"{k}.") for k in keys):
            # (an element of a list key, like agent.hidden.0, is Hydra's to check)
            alias = AGENT_ALIASES.get(key.rsplit(".", 1)[-1])
            nearest = [f"agent.{alias}"] if alias else difflib.get_close_matches(key, keys, n=1)
            hint = (
                f" (did you mean {nearest[0]}?)"
                if nearest
                else f"; the keys are listed by `{Path(sys.argv[0]).name} --cfg job`"
            )
            raise ConfigError(f"unknown config key '{key}' in '{override.input_line}'{hint}")


def check_plugins(overrides: list) -> None:
    """Refuse a Hydra launcher or sweeper whose plugin is not installed in one line naming the extra,
    where Hydra would say in several only that the option is missing: one chosen on the command line
    (``hydra/launcher=joblib`` without the sweep extra) or by the defaults of a chosen config
    (``experiment=tune/sarsa_best`` picks ``hydra/sweeper=optuna``)."""
    groups = config_groups()
    for override in overrides:
        group = override.key_or_group
        if group in groups:
            for option in chosen_options(override):
                for plugin in plugin_choices(group, option):
                    check_plugin(*plugin, chosen_by=f"{group}={option}")
        elif group.startswith("hydra/"):
            check_plugin(group, str(override.value()))


def check_plugin(group: str, option: str, chosen_by: str | None = None) -> None:
    """Refuse ``group=option`` (``hydra/sweeper=optuna``) if it is a Hydra plugin of an extra that is not installed.

    :param group: a Hydra config group, ``hydra/launcher`` or ``hydra/sweeper``.
    :param option: the option chosen in it.
    :param chosen_by: the choice whose defaults picked it (``experiment=tune/sarsa_best``); None: the command line.
    """
    for (plugin_group, prefix), module in HYDRA_PLUGINS.items():
        if group == plugin_group and option.startswith(prefix) and importlib.util.find_spec(module) is None:
            where = f"{group}={option}" if chosen_by is None else f"{chosen_by} ({group}={option})"
            raise ConfigError(f"{where} needs its Hydra plugin: {EXTRA_MODULES[module].install}")


def plugin_choices(group: str, option: str) -> Iterator[tuple[str, str]]:
    """Each ``(hydra/GROUP, OPTION)`` the defaults list of the config ``group=option`` picks, directly or
    through a config it includes (``experiment=tune/sarsa_best``: ``tune/base`` picks ``hydra/sweeper=optuna``).

    :param group: a config group of ``conf/`` (``experiment``).
    :param option: one of its options (``tune/sarsa_best``); none is picked by an option without a file
        (an absent optional default; an unknown option is refused by :func:`check_group_option`).
    """
    if not (CONFIG_DIR / group / f"{option}.yaml").is_file():
        return
    for entry in option_values(group, option).get("defaults") or []:
        if isinstance(entry, str):  # a config of the option's own group (tune/base), or _self_
            if entry != "_self_":
                yield from plugin_choices(group, entry)
            continue
        for key, value in entry.items():  # {[override |optional ]GROUP: OPTION}
            name = key.split()[-1]
            path = name[1:] if name.startswith("/") else f"{group}/{name}"  # a GROUP without / is below the option's
            if not isinstance(value, str):
                continue
            if path.startswith("hydra/"):
                yield path, value
            else:
                yield from plugin_choices(path, value)


# Keys of a mapping whose entries the user names freely (``env.kwargs.NAME=VALUE``): Hydra adds or
# replaces them (``++``) where it would refuse a key its option does not already have.
OPEN_MAPPINGS = ("env.kwargs.",)


def open_mapping_overrides(argv: list[str]) -> list[str]:
    """``argv`` with every plain ``env.kwargs.NAME=VALUE`` as ``++env.kwargs.NAME=VALUE``.

    :param argv: the command line's words after the program.
    """
    return ["++" + word if word.startswith(OPEN_MAPPINGS) and "=" in word else word for word in argv]


def schema_types(schema: type, prefix: str = "") -> dict[str, Any]:
    """Every dotted leaf key of ``schema`` -> its declared type (``typing`` form)."""
    hints = typing.get_type_hints(schema)
    types: dict[str, Any] = {}
    for f in dataclasses.fields(schema):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            types.update(schema_types(kind, f"{prefix}{f.name}."))  # type: ignore[arg-type]
        else:
            types[prefix + f.name] = kind
    return types


def expected(kind: Any) -> str:
    """A declared type as the user reads it: ``a float``, ``one of cpu|cuda|auto``, ``a list of integers``."""
    args = typing.get_args(kind)
    if typing.get_origin(kind) is typing.Union:
        return " or ".join(expected(a) for a in args if a is not type(None)) + " (or null)"
    if typing.get_origin(kind) in (list, typing.List):  # noqa: UP006
        if args and isinstance(args[0], type) and issubclass(args[0], enum.Enum):
            return "a list of " + "|".join(str(m.value) for m in args[0])
        return f"a list of {expected(args[0]).split(' ', 1)[-1]}s" if args else "a list"
    if typing.get_origin(kind) in (dict, typing.Dict):  # noqa: UP006
        return "a mapping {key: value}"
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return "one of " + "|".join(str(m.value) for m in kind)
    return {bool: "true or false", int: "an integer", float: "a float", str: "a string"}.get(kind, "another value")


def check_value_type(override, kind: Any) -> None:
    """Refuse a value the schema's type cannot hold (``agent.lr=fast``) in one line, before Hydra does
    so in six. Each value of a sweep is tried; interpolations are left to Hydra."""
    if kind is Any or override.is_delete():
        return
    try:
        values = list(override.sweep_iterator()) if override.is_sweep_override() else [override.value()]
    except HydraException:
        return  # a sweep Hydra expands itself (range, glob): its own errors
    schema = OmegaConf.structured(TrainConfig)
    for value in values:
        if isinstance(value, str) and "${" in value:
            continue
        try:
            OmegaConf.update(schema, override.key_or_group, value, merge=True)
        except (OmegaConfBaseException, ValueError, TypeError):
            raw = override.input_line.split("=", 1)[-1]
            shown = str(value) if override.is_sweep_override() else raw
            raise ConfigError(f"{override.key_or_group}={shown}: expected {expected(kind)}") from None


# Hydra's own command-line flags, and whether each takes a value (``--info`` may or may not: its value
# is one of Hydra's info topics); every other word is an override.
HYDRA_FLAGS = {
    **dict.fromkeys(("-m", "--multirun", "-r", "--run", "--hydra-help", "-h", "--help", "--version"), False),
    **dict.fromkeys(("--resolve", "-sc", "--shell-completion"), False),
    **dict.fromkeys(("-cn", "--config-name", "-cp", "--config-path", "-cd", "--config-dir"), True),
    **dict.fromkeys(("-c", "--cfg", "-p", "--package", "--experimental-rerun"), True),
}
INFO_FLAGS = ("-i", "--info")
INFO_TOPICS = ("all", "config", "defaults", "defaults-tree", "plugins", "searchpath")


# Hydra runs in one of these modes; two on one command line are its ValueError and a traceback.
HYDRA_MODES = {
    "--run": ("-r", "--run"),
    "--multirun": ("-m", "--multirun"),
    "--cfg": ("-c", "--cfg"),
    "--info": INFO_FLAGS,
    "--shell-completion": ("-sc", "--shell-completion"),
}


def check_hydra_modes(argv: list[str]) -> None:
    """Refuse two of Hydra's modes on one command line (``-m ... --cfg job``) in one line."""
    flags = {word.split("=", 1)[0] for word in argv if word.startswith("-")}
    chosen = [mode for mode, spellings in HYDRA_MODES.items() if flags & set(spellings)]
    if len(chosen) > 1:
        modes = ", ".join(HYDRA_MODES)
        raise ConfigError(f"{' and '.join(chosen)} cannot be given together: Hydra runs in one of {modes}")


def override_words(argv: list[str]) -> list[str]:
    """The overrides of a command line: its words that are not Hydra's flags or their values."""
    words, rest = [], iter(argv)
    for word in rest:
        flag = word.split("=", 1)[0] if word.startswith("-") else word
        if word.startswith("-") and "=" in word and flag in {*HYDRA_FLAGS, *INFO_FLAGS}:
            continue  # --flag=value
        if flag in INFO_FLAGS:
            topic = next(rest, None)
            if topic is not None and topic not in INFO_TOPICS:
                words.append(topic)
        elif flag in HYDRA_FLAGS:
            if HYDRA_FLAGS[flag]:
                next(rest, None)
        else:
            words.append(word)
    return words


def chosen_options(override) -> list[str]:
    """The options a group's override chooses: each of a sweep's, or its one."""
    if override.is_sweep_override():
        return list(override.sweep_string_iterator())
    return [override.get_value_element_as_str()]


def check_group_option(group: str, override) -> None:
    options = group_options(group)
    for option in chosen_options(override):
        if option not in options and option != "null":
            nearest = difflib.get_close_matches(option, options, n=1)
            hint = f"did you mean {group}={nearest[0]}? " if nearest else ""
            raise ConfigError(f"{group}={option}: no such option ({hint}choose from {', '.join(options)})")
