"""The second edition's sweeps compose as results/v2/VERDICT_RULES.md registers them: each method option is its
learner with its exchange, 3 seeds a map for SARSA and 1 for Double DQN, on evaluation maps 0..M-1."""

import pytest
from conftest import compose_config, sweep_params

from dqn_transfer.config import TrainConfig, validate
from dqn_transfer.enums import Exchange

# The registered methods of the main hypothesis: (learner, exchange, parameter sharing with agent ids, mixer).
METHODS = {
    "sarsa_none": ("sarsa", "none", False, "none"),
    "sarsa_best": ("sarsa", "best", False, "none"),
    "sarsa_shared_replay": ("sarsa", "shared_replay", False, "none"),
    "sarsa_confidence": ("sarsa", "confidence", False, "none"),
    "sarsa_advice": ("sarsa", "advice", False, "none"),
    "double_dqn_none": ("double_dqn", "none", False, "none"),
    "double_dqn_best": ("double_dqn", "best", False, "none"),
    "double_dqn_shared_replay": ("double_dqn", "shared_replay", False, "none"),
    "double_dqn_experience": ("double_dqn", "experience", False, "none"),
    "double_dqn_shared_id": ("double_dqn", "none", True, "none"),
    "double_dqn_vdn": ("double_dqn", "none", False, "vdn"),
}
SEEDS = {"sarsa": 3, "double_dqn": 1}  # the primary learner 3 seeds a map, the deep one 1


def test_the_hypothesis_sweep_is_every_registered_method_in_both_modes():
    assert sweep_params("v2/hypothesis") == {"method": list(METHODS), "mode": ["cooperative", "deliberative"]}


@pytest.mark.parametrize("method", METHODS)
def test_each_method_is_its_learner_with_its_exchange(method):
    algorithm, exchange, shared_id, mixer = METHODS[method]
    config: TrainConfig = compose_config("experiment=v2/hypothesis", f"method={method}")
    validate(config)
    assert config.agent.algorithm.value == algorithm
    assert Exchange(config.transfer.exchange).value == exchange
    assert (config.agent.share_parameters, config.agent.agent_id_input) == (shared_id, shared_id)
    assert config.agent.mixer.value == mixer
    assert (config.replicas.maps, config.replicas.seeds) == (40, SEEDS[algorithm])
    assert config.env.map_seed == 0  # evaluation maps 0..39: the tuning (1000..) and pilot (2000..) maps are apart
    assert (config.env.num_agents, config.env.size, config.env.mode.value) == (4, 8, "cooperative")


def test_claim1_runs_sarsa_on_thirty_one_chest_maps():
    assert sweep_params("v2/claim1") == {"mode": ["competitive", "cooperative"]}
    config: TrainConfig = compose_config("experiment=v2/claim1", "mode=cooperative")
    assert config.agent.algorithm.value == "sarsa"
    assert (config.env.num_agents, config.env.num_treasures, config.env.num_traps) == (2, 1, 1)
    assert (config.replicas.maps, config.replicas.seeds, config.env.map_seed) == (30, 3, 0)


@pytest.mark.parametrize("condition", ["scratch_matched", "scratch", "same_map", "same_map_own"])
@pytest.mark.parametrize("method", ["sarsa_none", "double_dqn_none"])
def test_claim3_runs_every_condition_for_both_learners(condition, method):
    assert sweep_params("v2/transfer") == {
        "condition": ["scratch_matched", "scratch", "same_map", "same_map_own"],
        "method": ["sarsa_none", "double_dqn_none"],
    }
    config: TrainConfig = compose_config("experiment=v2/transfer", f"condition={condition}", f"method={method}")
    validate(config)
    learner = METHODS[method][0]
    assert (config.replicas.maps, config.replicas.seeds) == (30, SEEDS[learner])
    assert config.transfer.enabled == condition.startswith("same_map")
    assert config.transfer.source_task.value == ("per_agent" if condition == "same_map_own" else "single")
    assert not config.transfer.chest_aware


def test_the_chest_aware_condition_is_swept_for_sarsa_alone():
    assert sweep_params("v2/transfer_aware") == {"condition": ["same_map_own_aware"], "method": ["sarsa_none"]}
    config: TrainConfig = compose_config("experiment=v2/transfer_aware")
    validate(config)
    assert config.agent.algorithm.value == "sarsa" and config.transfer.chest_aware
    assert config.transfer.source_task.value == "per_agent" and (config.replicas.maps, config.replicas.seeds) == (30, 3)


def test_claim2_grows_the_team_on_one_map_size_at_two_contentions():
    assert sweep_params("v2/claim2") == {
        "env": ["study_fixed/m2", "study_fixed/m3", "study_fixed/m4", "study_fixed/m6"],
        "env.contention": ["high", "low"],
        "mode": ["competitive", "cooperative", "deliberative"],
    }
    for m in (2, 3, 4, 6):
        config: TrainConfig = compose_config(
            "experiment=v2/claim2", f"env=study_fixed/m{m}", "env.contention=low", "mode=deliberative"
        )
        validate(config)
        assert (config.env.size, config.env.num_agents, config.env.num_treasures, config.env.num_traps) == (10, m, m, m)
        assert config.agent.algorithm.value == "sarsa" and config.env.contention.value == "low"
        assert (config.replicas.maps, config.replicas.seeds, config.env.map_seed) == (30, 3, 0)
