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
                cycle = path[path.index(target) :] + [target] if target in path else [module, target]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target, path + [target])
        state[module] = 2

    for module in sorted(GRAPH):
        if module not in state:
            visit(module, [module])


def part_of(module: str) -> str:
    """``dqn_transfer.transfer.mapping`` is in the part ``transfer``; a top-level module is its own part."""
    return module.split(".")[1] if "." in module else module


# What each part may import besides itself: the layers of docs/architecture.md, bottom to top. A part
# that is not listed here fails the test below, so a new subpackage must take its place in the stack.
LEAVES = {"enums", "documented", "timing", "compiled"}
ALLOWED = {
    "enums": set(),
    "compiled": set(),  # numba's njit with its cache
    "documented": set(),
    "timing": set(),
    "envs": LEAVES,  # the game knows no learner and no config
    "config": LEAVES | {"envs"},  # the schemas (env's is the game's own EnvConfig)
    "agents": LEAVES | {"config"},  # learners never see the game or a file
    "storage": LEAVES,  # checkpoint files and the run directory's names
    "evaluation": LEAVES | {"envs", "agents"},  # greedy episodes of a game and a policy
    "transfer": LEAVES | {"envs", "config", "agents", "storage"},
    "exchange": LEAVES | {"config", "agents"},  # knowledge exchange inside a team: the protocol and its methods
    "training": LEAVES | {"envs", "config", "agents", "storage", "evaluation", "transfer", "exchange"},
    "sources": LEAVES | {"envs", "config", "storage", "transfer", "training"},
    "sharing": LEAVES | {"envs", "config", "agents", "storage", "evaluation"},
    "analysis": LEAVES | {"storage"},  # reads run directories, never live objects
    # runs go through a subprocess; evaluation: the scripted bounds (greedy team) drawn beside the learners;
    # training: a planned run's memory estimate, which splits a cell's maps into multiruns that fit
    "experiments": LEAVES | {"envs", "config", "storage", "analysis", "evaluation", "training"},
    "benchmark": LEAVES | {"envs", "config", "agents", "storage", "evaluation", "training"},
    "cli": {part_of(m) for m in GRAPH} - {"dqn_transfer", "cli", "play"},  # the entry points
    "play": {"cli"},  # `python -m dqn_transfer.play`, an alias
}
# Inside a part, the modules that may not import each other.
FORBIDDEN_INSIDE = {
    "dqn_transfer.sources.run_cache": ("dqn_transfer.sources.resolve", "dqn_transfer.sources.curriculum"),
    "dqn_transfer.sources.resolve": ("dqn_transfer.sources.curriculum",),
    "dqn_transfer.config.schema": ("dqn_transfer.config.help",),
    "dqn_transfer.transfer.mapping": ("dqn_transfer.transfer.warm_start",),
}
# Entry points: the command-line modules, and `python -m dqn_transfer.play` (dqn-transfer-play's short name).
ENTRY_POINTS = ("dqn_transfer.cli", "dqn_transfer.play")
MAX_TOP_LEVEL_MODULES = 8


@pytest.mark.parametrize("part", sorted(ALLOWED))
def test_each_part_imports_only_what_lies_below_it(part):
    offending = {
        module: sorted(t for t in targets if part_of(t) not in ALLOWED[part] | {part, "dqn_transfer"})
        for module, targets in GRAPH.items()
        if part_of(module) == part
    }
    assert not {m: t for m, t in offending.items() if t}, offending


def test_every_part_has_its_place_in_the_stack():
    assert {part_of(m) for m in GRAPH} - {"dqn_transfer"} <= set(ALLOWED)


@pytest.mark.parametrize("module", sorted(FORBIDDEN_INSIDE))
def test_modules_inside_a_part_point_one_way(module):
    assert not [t for t in GRAPH[module] if t.startswith(FORBIDDEN_INSIDE[module])]


def test_the_top_level_holds_few_modules():
    modules = sorted(p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py")
    assert len(modules) <= MAX_TOP_LEVEL_MODULES, modules


def test_nothing_imports_the_entry_points():
    users = {
        module
        for module, targets in GRAPH.items()
        if not module.startswith(ENTRY_POINTS) and any(t.startswith(ENTRY_POINTS) for t in targets)
    }
    assert not users
    assert not any(t.startswith("dqn_transfer.play") for targets in GRAPH.values() for t in targets)
