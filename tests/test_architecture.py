"""The package's imports point one way (docs/architecture.md): no cycle, counting imports inside
functions, and each layer imports only the layers below it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "dqn_transfer"


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every ``dqn_transfer`` module ``path`` imports, at any depth of the file (functions included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("dqn_transfer"):
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("dqn_transfer"))
    return found


GRAPH = {module_name(path): imports_of(path) for path in PACKAGE.rglob("*.py")}


def resolve(name: str) -> str:
    """``from dqn_transfer.agents import X`` is an edge to the package ``dqn_transfer.agents``."""
    return name if name in GRAPH else name.rsplit(".", 1)[0]


def test_the_import_graph_has_no_cycle():
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(resolve(t) for t in GRAPH[module]):
            if target == module or target not in GRAPH:
                continue
            if state.get(target) == 1:
                cycle = path[path.index(target):] + [target] if target in path else [module, target]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target, path + [target])
        state[module] = 2

    for module in sorted(GRAPH):
        if module not in state:
            visit(module, [module])


# What each part may not import (the arrows of docs/architecture.md, read backwards).
FORBIDDEN = {
    "dqn_transfer.enums": ("dqn_transfer.",),
    "dqn_transfer.run_dir": ("dqn_transfer.",),
    "dqn_transfer.documented": ("dqn_transfer.",),
    "dqn_transfer.config_help": ("dqn_transfer.trainer", "dqn_transfer.agents", "dqn_transfer.cli"),
    "dqn_transfer.envs": ("dqn_transfer.agents", "dqn_transfer.config", "dqn_transfer.trainer",
                          "dqn_transfer.checkpoint", "dqn_transfer.analysis"),
    "dqn_transfer.agents": ("dqn_transfer.envs", "dqn_transfer.trainer", "dqn_transfer.checkpoint",
                            "dqn_transfer.sources", "dqn_transfer.warm_start"),
    "dqn_transfer.checkpoint": ("dqn_transfer.trainer", "dqn_transfer.agents", "dqn_transfer.envs"),
    "dqn_transfer.transfer_mapping": ("dqn_transfer.trainer", "dqn_transfer.agents", "dqn_transfer.envs"),
    "dqn_transfer.trainer": ("dqn_transfer.sources", "dqn_transfer.cli", "dqn_transfer.experiments"),
    "dqn_transfer.analysis": ("dqn_transfer.trainer", "dqn_transfer.agents", "dqn_transfer.envs",
                              "dqn_transfer.experiments", "dqn_transfer.cli"),
    "dqn_transfer.experiments": ("dqn_transfer.trainer", "dqn_transfer.cli"),
    "dqn_transfer.watch": ("dqn_transfer.trainer", "dqn_transfer.checkpoint", "dqn_transfer.cli"),
    "dqn_transfer.run_cache": ("dqn_transfer.sources", "dqn_transfer.curriculum", "dqn_transfer.cli"),
    "dqn_transfer.sources": ("dqn_transfer.curriculum", "dqn_transfer.cli"),
    "dqn_transfer.curriculum": ("dqn_transfer.cli", "dqn_transfer.experiments"),
    "dqn_transfer.team": ("dqn_transfer.trainer", "dqn_transfer.sources", "dqn_transfer.cli"),
    "dqn_transfer.model_card": ("dqn_transfer.trainer", "dqn_transfer.sources", "dqn_transfer.cli"),
}
# Entry points: the command-line modules, and `python -m dqn_transfer.play` (dqn-transfer-play's short name).
ENTRY_POINTS = ("dqn_transfer.cli", "dqn_transfer.play")


@pytest.mark.parametrize("part", sorted(FORBIDDEN))
def test_each_part_imports_only_what_lies_below_it(part):
    offending = {module: sorted(target for target in targets if target.startswith(FORBIDDEN[part]))
                 for module, targets in GRAPH.items() if module == part or module.startswith(part + ".")}
    assert not {m: t for m, t in offending.items() if t}, offending


def test_nothing_imports_the_entry_points():
    users = {module for module, targets in GRAPH.items() if not module.startswith(ENTRY_POINTS)
             and any(t.startswith(ENTRY_POINTS) for t in targets)}
    assert not users
    assert not any(t.startswith("dqn_transfer.play") for targets in GRAPH.values() for t in targets)
