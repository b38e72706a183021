"""A map's contention for the agents' nearest chests, ``env.contention`` and the fixed-size ladder
(docs/game.md): hand-worked maps, generated maps checked by an independent BFS, the refusals."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from conftest import assert_one_error_line
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dqn_transfer.analysis.marl_eval import task_name
from dqn_transfer.cli.contention import main as contention_main
from dqn_transfer.config import CONFIG_DIR, ConfigError, TrainConfig, register_configs, validate
from dqn_transfer.enums import Contention
from dqn_transfer.envs import maps
from dqn_transfer.envs.maps import generate_layout, optimal_team_return, parse_layout, resolve_map
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.evaluation.contention import map_contention
from dqn_transfer.experiments.raw_data import map_optimum
from dqn_transfer.experiments.settings import on_ladder
from dqn_transfer.training.plan import plan_run

# ------------------------------------------------------------------ maps worked out by hand

# Chest 0 at row 0, col 2; chest 1 at row 4, col 4. Agent 0 is 2 steps from chest 0 and 8 from chest 1,
# agent 1 2 and 4: both nearest to chest 0. The least total (2 + 4 = 6, against 8 + 2) sends agent 1 on to
# chest 1, past its nearest.
BOTH_NEAREST_TO_ONE = """
0.T.1
.....
.....
.....
....T
"""
# Agent 0: 2 steps to chest 0 (row 0), 6 to chest 1 (row 4); agent 1 the other way round.
ONE_EACH = """
0.T..
.....
.....
.....
1.T..
"""
# Agent 0 is 2 steps from both chests: the tie goes to chest 0, which is also agent 1's nearest (4 against 8).
TIE_TO_THE_LOWER_CHEST = """
T.0.T
.....
.....
.....
1....
"""
# Through the trap (row 2, col 1) agent 0 would be 6 steps from chest 0; around it, down column 0 and back
# up column 2, 8 steps, so its nearest is chest 1 (row 4, col 3: 7 steps), agent 1's too (1 step, chest 0
# 6). Optimum: agent 0 to chest 0 (8 + 1 = 9, against 7 + 6).
AROUND_THE_TRAP = """
0#T..
.#...
.X...
.....
...T1
"""
# Agents 0 and 1 both nearest to chest 0 (2 steps each); agent 2 to chest 1 (4 steps, chest 0 6): 2 of 3.
TWO_OF_THREE = """
0.T.1
.....
.....
.....
2...T
"""


@pytest.mark.parametrize(
    "layout, nearest, contention",
    [
        (BOTH_NEAREST_TO_ONE, [0, 0], 1.0),
        (ONE_EACH, [0, 1], 0.0),
        (TIE_TO_THE_LOWER_CHEST, [0, 0], 1.0),
        (AROUND_THE_TRAP, [1, 1], 1.0),
        (TWO_OF_THREE, [0, 0, 1], 2 / 3),
    ],
    ids=["both_nearest_to_one", "one_each", "tie_to_the_lower_chest", "around_the_trap", "two_of_three"],
)
def test_nearest_chests_and_contention_of_hand_worked_maps(layout, nearest, contention):
    grid_map = parse_layout(layout)
    assert grid_map.nearest_chests().tolist() == nearest
    assert grid_map.contention() == pytest.approx(contention)


@pytest.mark.parametrize(
    "layout, not_nearest",
    [(BOTH_NEAREST_TO_ONE, 0.5), (ONE_EACH, 0.0), (AROUND_THE_TRAP, 0.5)],
    ids=["both_nearest_to_one", "one_each", "around_the_trap"],
)
def test_map_contention_counts_agents_the_optimum_sends_past_their_nearest_chest(layout, not_nearest):
    measured = map_contention(parse_layout(layout))
    assert measured.not_nearest == not_nearest
    assert measured.contention == parse_layout(layout).contention()


# ------------------------------------------------------------------ generated maps, checked independently


def independent_nearest(layout: str) -> list[int]:
    """Each agent's nearest chest by a BFS written here: 4-moves avoiding '#' and 'X', chests numbered
    row-major, the lower number on equal distance."""
    rows = layout.split("\n")
    n = len(rows)
    chests = [(r, c) for r in range(n) for c in range(n) if rows[r][c] == "T"]
    starts = sorted((int(ch), (r, c)) for r, row in enumerate(rows) for c, ch in enumerate(row) if ch.isdigit())
    nearest = []
    for _, start in starts:
        dist = {start: 0}
        queue = deque([start])
        while queue:
            r, c = queue.popleft()
            for nxt in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                if 0 <= nxt[0] < n and 0 <= nxt[1] < n and nxt not in dist and rows[nxt[0]][nxt[1]] not in "#X":
                    dist[nxt] = dist[(r, c)] + 1
                    queue.append(nxt)
        lengths = [dist[chest] for chest in chests]
        nearest.append(lengths.index(min(lengths)))
    return nearest


@pytest.mark.parametrize("m", [2, 3, 6])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_high_maps_share_every_nearest_chest_and_low_maps_none(m, seed):
    high = generate_layout(10, m, m, m, 0.1, seed=seed, contention="high")
    low = generate_layout(10, m, m, m, 0.1, seed=seed, contention=Contention.low)
    nearest = independent_nearest(high)
    assert all(nearest.count(chest) > 1 for chest in nearest), high
    assert len(set(independent_nearest(low))) == m, low
    for layout in (high, low):  # every map rule holds, the counts are the asked ones
        grid_map = parse_layout(layout)
        assert (grid_map.size, grid_map.num_treasures, grid_map.num_traps, grid_map.num_agents) == (10, m, m, m)
        assert len(grid_map.obstacles) == 10


# Layouts generate_layout gave (size, chests, traps, agents, complexity, seed) before env.contention existed,
# recorded at main's code (5595e22).
BEFORE_CONTENTION = {
    (6, 2, 2, 2, 0.1, 0): "..#.#.\n.X..1.\n...X..\nT.0...\n..T...\n#...#.",
    (8, 4, 4, 4, 0.1, 3): "#X###1..\n......3.\n.T..2..0\n....X..#\n.T.....T\n....#...\nX...X...\n.......T",
    (10, 6, 6, 6, 0.1, 7): (
        "....#.T..X\n......T...\n....#.#..X\n4T#.T..T..\nT.#.......\n"
        "#..##..50.\nX.....1...\n#.X......2\n..X.....#.\n...3..X..."
    ),
    (10, 2, 2, 2, 0.1, 11): (
        "..........\n...X......\n....1.....\n...T..#..#\n.....T.#..\n"
        "....#.....\n....X.....\n#.#..0....\n..#....#..\n#.....#..."
    ),
}


@pytest.mark.parametrize("args", list(BEFORE_CONTENTION))
def test_contention_any_draws_the_maps_of_before(args):
    *counts, seed = args
    assert generate_layout(*counts, seed=seed) == BEFORE_CONTENTION[args]
    assert generate_layout(*counts, seed=seed, contention="any") == BEFORE_CONTENTION[args]
    assert resolve_map(*counts, map_seed=seed).layout == BEFORE_CONTENTION[args]


def test_a_contention_takes_the_seeds_first_candidate_that_meets_it():
    """Candidate k is drawn from the k-th child of SeedSequence(seed); the same seed, the same map."""
    seed, counts = 4, (10, 4, 4, 4, 0.1)
    for contention in ("high", "low"):
        layout = generate_layout(*counts, seed=seed, contention=contention)
        assert layout == generate_layout(*counts, seed=seed, contention=contention)
        for k in range(maps.CONTENTION_CANDIDATES):
            rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(k + 1)[k])
            candidate = maps._draw_layout(*counts, rng)
            nearest = independent_nearest(candidate)
            shared = [nearest.count(chest) > 1 for chest in nearest]
            if all(shared) if contention == "high" else not any(shared):
                break
        assert layout == candidate
    assert generate_layout(*counts, seed=seed, contention="high") != generate_layout(*counts, seed=5, contention="high")


# ------------------------------------------------------------------ refusals, each one clear message


def test_a_layout_with_a_contention_is_refused():
    with pytest.raises(ValueError, match="^contention=high chooses among generated maps; a layout fixes the map"):
        resolve_map(layout=ONE_EACH, contention="high")
    assert resolve_map(layout=ONE_EACH, contention="any").layout == ONE_EACH.strip()
    config = TrainConfig(env=EnvConfig(layout=ONE_EACH, contention=Contention.low))
    with pytest.raises(ConfigError, match="^env.contention=low chooses among generated maps; a layout fixes the map"):
        validate(config)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(num_agents=3, contention="low"), "contention=low gives every agent a nearest chest of its own: "),
        (dict(num_agents=1, contention="high"), "contention=high needs agents that share a nearest chest"),
        (dict(contention="medium"), "contention must be one of any, high, low; got 'medium'"),
    ],
)
def test_contentions_that_cannot_be_met_are_refused(kwargs, message):
    with pytest.raises(ValueError, match="^" + message):
        generate_layout(8, 2, seed=0, **kwargs)


def test_running_out_of_candidates_names_the_settings(monkeypatch):
    # Candidate 0 of seed 0 (6 agents, 10x10) has contention between 0 and 1: neither low nor high.
    candidate = maps._draw_layout(10, 6, 6, 6, 0.1, np.random.default_rng(np.random.SeedSequence(0).spawn(1)[0]))
    assert 0 < parse_layout(candidate).contention() < 1
    monkeypatch.setattr(maps, "CONTENTION_CANDIDATES", 1)
    with pytest.raises(ValueError) as info:
        generate_layout(10, 6, 6, 6, 0.1, seed=0, contention="low")
    assert str(info.value) == (
        "no map of contention=low among the 1 candidates of seed 0 "
        "(size=10, num_treasures=6, num_traps=6, num_agents=6, complexity=0.1)"
    )


# ------------------------------------------------------------------ through the config, the study and the CLI

register_configs()


def compose_config(*overrides: str) -> TrainConfig:
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return OmegaConf.to_object(compose(config_name="config", overrides=list(overrides)))


def test_a_run_of_the_fixed_ladder_plays_high_contention_maps():
    config = compose_config("env=study_fixed/m4", "env.contention=high", "replicas.maps=3")
    plan = plan_run(config)
    assert [replica.config.env.map_seed for replica in plan.replicas] == [0, 1, 2]
    for replica in plan.replicas:
        grid_map = replica.grid_map
        assert (grid_map.size, grid_map.num_agents, grid_map.num_treasures) == (10, 4, 4)
        nearest = independent_nearest(grid_map.layout)
        assert all(nearest.count(chest) > 1 for chest in nearest)


def test_the_stored_config_rebuilds_the_contention_map():
    """The study's raw data reads a run's map optimum from its stored env config, contention included."""
    env = {"size": 10, "num_treasures": 3, "num_traps": 3, "num_agents": 3, "complexity": 0.1, "map_seed": 2}
    for contention in ("high", "low"):
        grid_map = parse_layout(generate_layout(10, 3, 3, 3, 0.1, seed=2, contention=contention))
        assert map_optimum({"env": {**env, "contention": contention}}) == optimal_team_return(grid_map, 3)
    assert map_optimum({"env": env}) == optimal_team_return(parse_layout(generate_layout(10, 3, 3, 3, 0.1, seed=2)), 3)


def test_both_ladders_are_claim_2s_maps():
    rung = {"size": 10, "num_treasures": 3, "num_traps": 3, "num_agents": 3, "complexity": 0.1, "map_seed": 5}
    assert on_ladder(rung)  # study_fixed/m3
    assert on_ladder({**rung, "size": 7})  # study/m3
    assert not on_ladder({**rung, "size": 9})
    assert not on_ladder({**rung, "layout": ONE_EACH})


def test_the_marl_eval_task_names_a_contention():
    env = {"mode": "cooperative", "num_agents": 4, "size": 10, "map_seed": 3}
    assert task_name({"env": env}) == "cooperative-4agents-10x10-map3"
    assert task_name({"env": {**env, "contention": "any"}}) == "cooperative-4agents-10x10-map3"
    assert task_name({"env": {**env, "contention": "high"}}) == "cooperative-4agents-10x10-map3-contention_high"


def test_the_command_prints_one_row_per_option_and_contention(capsys):
    assert contention_main(["study_fixed/m2", "study/m3", "--maps", "4"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("| env | contention | maps | mean contention | optimal chest not nearest |")
    rows = [line.split(" | ") for line in lines[2:]]
    assert [(row[0], row[1], row[2]) for row in rows] == [
        ("| study_fixed/m2", contention, "4") for contention in ("any", "high", "low")
    ] + [("| study/m3", contention, "4") for contention in ("any", "high", "low")]
    assert [row[3] for row in rows if row[1] != "any"] == ["1.000", "0.000", "1.000", "0.000"]
    assert [row[4] for row in rows if row[1] == "low"] == ["0.000", "0.000"]  # every agent's optimum its nearest


@pytest.mark.parametrize(
    "argv, message",
    [
        (["lbf"], "error: argument ENV: invalid choice: 'lbf'"),
        (["simple", "--maps", "0"], "error: --maps must be at least 1"),
        (["simple", "--contention", "medium"], "error: argument --contention: invalid choice: 'medium'"),
    ],
)
def test_the_command_refuses_bad_input_in_one_line(argv, message, capsys):
    assert_one_error_line(contention_main, argv, message, capsys)
