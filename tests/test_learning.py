"""Learning: SARSA and Double DQN solve a small fixed map within a step budget (seeded, CPU).

The map (one agent, one chest, an obstacle and a trap):

    0....
    .#...
    ...X.
    .....
    ....T

The shortest path from (0,0) to the chest at (4,4) is 8 moves (Manhattan distance; e.g. along the
top row, then down the right column), so the optimal return is 7 * (-1) + 100 = 93: every move costs
-1 except the last, which gets the +100 instead.
"""

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dqn_transfer.analysis.runs import read_metrics
from dqn_transfer.config import CONFIG_DIR, register_configs
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train

CONF_DIR = str(CONFIG_DIR)
LAYOUT = "0....\n.#...\n...X.\n.....\n....T"
OPTIMAL_RETURN = 93.0
register_configs()
# The layouts override env=simple's generation keys, which the game reports in one warning (tested in
# test_maps.py); here it is expected noise.
pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore:a layout fixes the map")]


def run(tmp_path: Path, *overrides: str) -> list[dict]:
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(
            config_name="config", overrides=["progress=false", "eval_every=500", "eval_episodes=1", *overrides]
        )
    cfg.env.layout = LAYOUT
    train(plan_run(OmegaConf.to_object(cfg)), tmp_path)
    return read_metrics(tmp_path)


def test_sarsa_finds_the_shortest_path(tmp_path):
    metrics = run(tmp_path, "agent=sarsa", "total_steps=5000", "seed=1")
    assert metrics[0]["success_rate"] == 0.0  # an all-zero table walks in circles until truncation
    assert metrics[-1]["success_rate"] == 1.0
    assert metrics[-1]["team_return"] == OPTIMAL_RETURN


def test_double_dqn_finds_the_shortest_path(tmp_path):
    metrics = run(tmp_path, "agent=double_dqn", "total_steps=3000", "seed=0", "agent.learning_starts=200")
    assert metrics[-1]["success_rate"] == 1.0
    assert metrics[-1]["team_return"] == OPTIMAL_RETURN


@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
def test_qlearning_team_collects_both_chests(tmp_path, mode):
    """Two agents, two chests, each chest 3 moves from one agent: 2 * (2 * -1 + 100) = 196."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=[
                "progress=false",
                "eval_every=1000",
                "eval_episodes=1",
                "agent=qlearning",
                f"mode={mode}",
                "total_steps=4000",
                "seed=0",
            ],
        )
    cfg.env.layout = "0..T\n....\n....\n1..T"
    train(plan_run(OmegaConf.to_object(cfg)), tmp_path)
    final = read_metrics(tmp_path)[-1]
    assert final["success_rate"] == 1.0
    assert final["team_return"] == 196.0
