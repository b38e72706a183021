"""Schema fields that carry their one-line description, so ``--help`` and the docs read it from the schema.

A config dataclass writes each key once, with its type, its default and what it means::

    lr: float = documented(1e-3, "Adam step size (DQN) or alpha (tabular)")

and :func:`describe` lists every key of a schema, nested groups included (``agent.lr``), with that
description and default. The module imports nothing of the package: the game's ``EnvConfig`` and the
trainer's schemas both use it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from enum import Enum
from typing import Any

HELP = "help"  # the field-metadata key of a description


def documented(default: Any = MISSING, doc: str = "", *, factory: Callable[[], Any] | Any = MISSING) -> Any:
    """A dataclass field with ``default`` (or ``factory`` for a mutable one) and its description ``doc``."""
    if not doc:
        raise ValueError("a documented field needs its description")
    return field(default=default, default_factory=factory, metadata={HELP: doc})


@dataclass(frozen=True)
class KeyDoc:
    """One key of a schema: its dotted name, its description and its default."""

    key: str
    doc: str
    default: Any


def describe(schema: type, prefix: str = "") -> list[KeyDoc]:
    """Every dotted key of ``schema`` in declaration order; a field holding a dataclass is a group,
    listed key by key under its name. Raises ``TypeError`` for a field without a description."""
    keys: list[KeyDoc] = []
    for f in fields(schema):
        default = f.default_factory() if f.default_factory is not MISSING else f.default
        if is_dataclass(default):
            keys += describe(type(default), f"{prefix}{f.name}.")
        elif HELP not in f.metadata:
            raise TypeError(f"{schema.__name__}.{f.name} has no description: declare it with documented()")
        else:
            keys.append(KeyDoc(prefix + f.name, f.metadata[HELP], default))
    return keys


def format_default(value: Any) -> str:
    """A default as it is typed on the command line: ``null``, ``true``, ``0.001``, ``[64,64]``, ``competitive``."""
    if isinstance(value, Enum):
        return str(value.value)
    if isinstance(value, list) and value and all(isinstance(item, Enum) for item in value):
        return "[" + ",".join(str(item.value) for item in value) + "]"
    if value is None or isinstance(value, (bool, list)):
        return json.dumps(value, separators=(",", ":"))
    return str(value)
