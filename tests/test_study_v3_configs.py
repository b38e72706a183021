"""The third edition's sweeps compose as results/VERDICT_RULES.md registers them: every run at the fixed
horizon with epsilon over its first half, each cell's methods and controls, its maps and seeds, and the
paper's two figures restaged beside their population answers."""

import pytest
from conftest import compose_config, sweep_params

from dqn_transfer.config import TrainConfig, validate
from dqn_transfer.enums import Exchange, SourceTask

# method option: (learner, exchange, parameter sharing with agent ids, mixer, warm start)
SARSA = {
    "sarsa_none": ("sarsa", "none", False, "none", False),
    "sarsa_best": ("sarsa", "best", False, "none", False),
    "sarsa_shared_replay": ("sarsa", "shared_replay", False, "none", False),
    "sarsa_confidence": ("sarsa", "confidence", False, "none", False),
    "sarsa_advice": ("sarsa", "advice", False, "none", False),
    "sarsa_sham": ("sarsa", "sham", False, "none", False),
    "sarsa_warm": ("sarsa", "none", False, "none", True),
}
DOUBLE_DQN = {
    "double_dqn_none": ("double_dqn", "none", False, "none", False),
    "double_dqn_best": ("double_dqn", "best", False, "none", False),
    "double_dqn_shared_replay": ("double_dqn", "shared_replay", False, "none", False),
    "double_dqn_experience": ("double_dqn", "experience", False, "none", False),
    "double_dqn_shared_id": ("double_dqn", "none", True, "none", False),
    "double_dqn_vdn": ("double_dqn", "none", False, "vdn", False),
    "double_dqn_sham": ("double_dqn", "sham", False, "none", False),
    "double_dqn_warm": ("double_dqn", "none", False, "none", True),
}
# experiment: (its sweep, maps, seeds)
CELLS = {
    "v3/sarsa": ({"method": list(SARSA), "env": ["study/m4_10", "study/m6"]}, 40, 3),
    "v3/double_dqn": ({"method": list(DOUBLE_DQN)}, 60, 3),
    "v3/lbf": ({"method": list(SARSA)}, 30, 3),
}


def _config(*overrides: str) -> TrainConfig:
    config = compose_config(*overrides)
    validate(config)
    return config


def _horizon(config: TrainConfig) -> None:
    """16,000 steps, epsilon over the first 8,000, an evaluation of 5 episodes every 500 steps."""
    assert (config.total_steps, config.agent.exploration_fraction) == (16_000, 0.5)
    assert (config.eval_every, config.eval_episodes) == (500, 5)


@pytest.mark.parametrize("experiment", CELLS)
def test_each_cell_sweeps_its_methods_and_controls(experiment):
    assert sweep_params(experiment) == CELLS[experiment][0]


@pytest.mark.parametrize(
    ("experiment", "method", "env"),
    [("v3/sarsa", m, e) for m in SARSA for e in ("study/m4_10", "study/m6")]
    + [("v3/double_dqn", m, None) for m in DOUBLE_DQN]
    + [("v3/lbf", m, None) for m in SARSA],
)
def test_each_run_is_its_method_on_its_cell_at_the_horizon(experiment, method, env):
    config = _config(f"experiment={experiment}", f"method={method}", *([f"env={env}"] if env else []))
    algorithm, exchange, shared_id, mixer, warm = {**SARSA, **DOUBLE_DQN}[method]
    _horizon(config)
    assert config.agent.algorithm.value == algorithm
    assert Exchange(config.transfer.exchange).value == exchange
    assert (config.agent.share_parameters, config.agent.agent_id_input) == (shared_id, shared_id)
    assert config.agent.mixer.value == mixer
    assert config.transfer.enabled == warm
    if warm:  # the team's own policy on the same map, trained for the horizon, exploring from 0.3
        assert SourceTask(config.transfer.source_task) is SourceTask.team and config.transfer.source is None
        assert (config.transfer.pretrain_steps, config.transfer.epsilon_start) == (16_000, 0.3)
    assert (config.replicas.maps, config.replicas.seeds) == CELLS[experiment][1:]
    assert config.env.map_seed == 0  # evaluation maps 0..M-1; tuning maps are 1000..
    if experiment == "v3/lbf":
        assert config.env.factory is not None and config.env.fixed_start
    else:
        team = 6 if env == "study/m6" else 4
        assert (config.env.size, config.env.num_agents, config.env.num_treasures, config.env.num_traps) == (
            10,
            team,
            team,
            team,
        )
        assert (config.env.mode.value, config.env.complexity) == ("cooperative", 0.1)


def test_figure_1_is_one_chest_cooperative_against_competitive_on_one_map_and_on_thirty():
    for experiment, maps, seeds, map_seed in (("v3/figure1", 1, 10, 6), ("v3/figure1_maps", 30, 3, 0)):
        assert sweep_params(experiment) == {"mode": ["competitive", "cooperative"]}
        config = _config(f"experiment={experiment}", "mode=cooperative")
        _horizon(config)
        env = config.env
        assert (env.size, env.num_treasures, env.num_traps, env.num_agents, env.map_seed) == (6, 1, 1, 2, map_seed)
        assert (config.replicas.maps, config.replicas.seeds, config.agent.algorithm.value) == (maps, seeds, "sarsa")


def test_figure_2_is_the_three_modes_as_the_team_grows_with_as_many_chests_and_traps():
    for experiment, maps, seeds in (("v3/figure2", 1, 10), ("v3/figure2_maps", 30, 3)):
        assert sweep_params(experiment) == {
            "env.num_agents": ["2", "3", "4", "6"],
            "mode": ["competitive", "cooperative", "deliberative"],
        }
        config = _config(f"experiment={experiment}", "env.num_agents=6", "mode=deliberative")
        _horizon(config)
        env = config.env
        assert (env.size, env.complexity, env.num_agents, env.num_treasures, env.num_traps) == (10, 0.15, 6, 6, 6)
        assert (config.replicas.maps, config.replicas.seeds, config.agent.algorithm.value) == (maps, seeds, "sarsa")
