"""Figure 2's maps: the complex map generated once, for teams of 1..K agents.

Figure 2 compares team sizes on the SAME map: the K-agent map is generated once and its m-agent
versions drop the start digits >= m (``fig2_m{m}.txt``). Changing ``env.num_agents`` instead would
generate a different map for every team size, confounding team size with the map.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from dqn_transfer.config import CONFIG_DIR
from dqn_transfer.envs import generate_layout, parse_layout

COMPLEX_ENV = CONFIG_DIR / "env" / "complex.yaml"


def team_map_layouts(size: int, num_treasures: int, num_traps: int | None, num_agents: int,
                     complexity: float, map_seed: int) -> dict[int, str]:
    """The ``num_agents``-agent generated map and its m-agent versions (starts >= m made free)."""
    full = generate_layout(size, num_treasures, num_traps, num_agents, complexity, seed=map_seed)
    layouts = {}
    for m in range(1, num_agents + 1):
        layout = "".join("." if ch.isdigit() and int(ch) >= m else ch for ch in full)
        parse_layout(layout)  # every map rule still holds: only starts became free cells
        layouts[m] = layout
    return layouts


def write_team_maps(directory: Path) -> list[Path]:
    """``fig2_m{1..K}.txt``: the complex map (conf/env/complex.yaml) for teams of 1..K agents."""
    env = yaml.safe_load(COMPLEX_ENV.read_text())
    layouts = team_map_layouts(env["size"], env["num_treasures"], env.get("num_traps"),
                               env.get("num_agents") or env["num_treasures"], env.get("complexity", 0.0),
                               env.get("map_seed", 0))
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for m, layout in layouts.items():
        path = directory / f"fig2_m{m}.txt"
        path.write_text(layout + "\n")
        paths.append(path)
    return paths
