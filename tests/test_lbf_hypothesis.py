"""The main hypothesis on Level-Based Foraging (``experiment=v2/lbf_hypothesis``): every exchange method of its
learner trains on LBF, a map seed is one fixed LBF instance (``env.fixed_start``), the runs are scored on
LBF's own normalised team return, and the experiment's sweep is the ten (learner, method) conditions.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import compose_config, read_metrics
from lbforaging.foraging.environment import ForagingEnv

from dqn_transfer.config import ConfigError, ReplicasConfig
from dqn_transfer.enums import Algorithm, Exchange
from dqn_transfer.envs import PettingZooGame
from dqn_transfer.experiments.raw_data import RunData, map_optimum
from dqn_transfer.experiments.scoring import score
from dqn_transfer.experiments.sweeps import count_jobs
from dqn_transfer.sharing.team import load_team
from dqn_transfer.storage.checkpoint import find_checkpoints, load_agent_checkpoint
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import train

LBF = "dqn_transfer.envs.lbf:parallel_env"
TINY = {"size": 5, "players": 2, "food": 1, "max_food_level": 1, "max_steps": 10}
SARSA_CONDITIONS = ("none", "best", "shared_replay", "confidence", "advice")
DQN_CONDITIONS = ("none", "best", "shared_replay", "experience", "shared_id")
CONDITIONS = [f"sarsa_{c}" for c in SARSA_CONDITIONS] + [f"double_dqn_{c}" for c in DQN_CONDITIONS]  # method=...
# A few hundred steps of every condition on a 5x5 field, two instances (map seeds 3 and 4) of one seed.
SHORT = (
    "env.kwargs.size=5",
    "env.kwargs.food=1",
    "env.kwargs.max_steps=10",
    "env.map_seed=3",
    "total_steps=300",
    "eval_every=150",
    "eval_episodes=2",
    "checkpoint_every=300",
    "replicas.seeds=1",
    "replicas.maps=2",
    "transfer.exchange_every=3",
    "transfer.advice_answer_from=2",
    "agent.learning_starts=50",
    "agent.batch_size=16",
    "agent.hidden=[16]",
)


def learner_and_method(condition: str) -> tuple[str, str]:
    """``double_dqn_best`` -> ``("double_dqn", "best")``."""
    learner = "sarsa" if condition.startswith("sarsa_") else "double_dqn"
    return learner, condition.removeprefix(f"{learner}_")


def first_observation(game: PettingZooGame, draw: int) -> np.ndarray:
    return game.reset(np.random.default_rng(draw))


# ------------------------------------------------------------------------------------ instances


def test_a_map_seed_is_one_lbf_instance_as_lbforaging_resets_it_with_that_seed():
    """Every episode of a fixed instance starts where lbforaging's own ``reset(seed=map_seed)`` does,
    whatever the episode generator draws; distinct map seeds give distinct fields."""
    instances = [PettingZooGame(LBF, TINY, reset_seed=seed) for seed in range(5)]
    for seed, game in enumerate(instances):
        lbf = ForagingEnv(
            players=2, min_player_level=1, max_player_level=2, min_food_level=1, max_food_level=1, field_size=(5, 5),
            max_num_food=1, sight=5, max_episode_steps=10, force_coop=False,
        )  # fmt: skip
        observations, _ = lbf.reset(seed=seed)
        expected = np.stack([np.asarray(o, dtype=np.float32) for o in observations])
        assert np.array_equal(first_observation(game, draw=0), expected)
        game.step(np.array([1, 2]))
        assert np.array_equal(first_observation(game, draw=99), expected)  # the next episode: the same start
        assert np.array_equal(first_observation(game.replica(), draw=7), expected)  # evaluation's game too
    starts = {first_observation(game, draw=0).tobytes() for game in instances}
    assert len(starts) == 5
    drawn = PettingZooGame(LBF, TINY)  # without a reset seed: each episode a new field, as before
    assert not np.array_equal(first_observation(drawn, draw=0), first_observation(drawn, draw=1))


def test_replicas_maps_plan_one_instance_per_map_seed():
    config = compose_config("env=lbf", "env.fixed_start=true", "env.map_seed=10", "replicas.maps=3")
    plan = plan_run(config)
    games = [replica.new_game() for replica in plan.replicas]
    assert [game.reset_seed for game in games] == [10, 11, 12]
    assert [replica.name for replica in plan.replicas] == ["seed_0-map_10", "seed_0-map_11", "seed_0-map_12"]
    assert all(game.recorded_env()["reset_seed"] == seed for game, seed in zip(games, (10, 11, 12)))
    assert "reset_seed" not in PettingZooGame(LBF, {}).recorded_env()  # a drawn game records what it did before


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (("env=lbf", "replicas.maps=2"), "replicas.maps=2 varies the map seed, which env.factory="),
        (("env=lbf", "replicas.maps=2"), "add env.fixed_start=true, or use replicas.seeds"),
        (("env.fixed_start=true",), "env.fixed_start=true fixes the episodes of another game (env.factory)"),
    ],
)
def test_maps_of_a_game_without_fixed_starts_and_fixed_starts_of_the_treasure_hunt_are_refused(overrides, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        plan_run(compose_config(*overrides))


# ------------------------------------------------------------------------------------ the score


def test_a_game_without_a_treasure_map_is_scored_on_its_own_team_return():
    """LBF's team return is already a fraction (1: all food loaded), so the score is the mean of its curve
    over training: the trapezoid area of (0, 0.2), (100, 0.6), (200, 1.0) is 40 + 80 = 120 over 200 steps."""
    config = dataclasses.asdict(compose_config("experiment=v2/lbf_hypothesis"))
    assert map_optimum(config) is None
    run = RunData(
        "v2/lbf_hypothesis", "0/seed_0-map_0", config, (0, 100, 200), {"team_return": (0.2, 0.6, 1.0)}, 0, None
    )
    assert score(run) == pytest.approx(0.6)
    assert run.unit == (0, 0)
    treasure = dataclasses.asdict(compose_config("env=simple"))
    assert map_optimum(treasure) is not None  # the treasure hunt keeps its map's optimum


# ------------------------------------------------------------------------------------ the experiment


def test_the_experiment_composes_into_its_ten_conditions():
    assert count_jobs("v2/lbf_hypothesis", []) == 10
    for condition in CONDITIONS:
        config = compose_config("experiment=v2/lbf_hypothesis", f"method={condition}")
        learner, method = learner_and_method(condition)
        assert config.agent.algorithm is Algorithm(learner)
        shared = method == "shared_id"
        assert config.transfer.exchange is Exchange("none" if shared else method)
        assert (config.agent.share_parameters, config.agent.agent_id_input) == (shared, shared)
        assert config.env.factory == LBF and config.env.fixed_start
        seeds = 3 if learner == "sarsa" else 1  # the registered design
        assert config.replicas == ReplicasConfig(seeds=seeds, maps=30) and config.total_steps == 8000
        assert config.env.kwargs == {
            "size": 8, "players": 2, "food": 2, "max_player_level": 1, "max_food_level": 1, "force_coop": False,
            "sight": None, "max_steps": 25,
        }  # fmt: skip
        plan_run(config)  # valid: no method is refused for its learner


# ------------------------------------------------------------------------------------ every method trains


def agent_tensors(run_dir: Path) -> list[dict[str, np.ndarray]]:
    return [load_agent_checkpoint(path)[0] for path in find_checkpoints(run_dir)]


def short_run(tmp_path: Path, condition: str) -> Path:
    run_dir = tmp_path / condition
    train(plan_run(compose_config("experiment=v2/lbf_hypothesis", f"method={condition}", *SHORT)), run_dir)
    return run_dir


@pytest.fixture(scope="module")
def controls(tmp_path_factory) -> dict[str, Path]:
    """Each learner's run without exchange, which every method of it is compared with."""
    tmp = tmp_path_factory.mktemp("controls")
    return {learner: short_run(tmp, f"{learner}_none") for learner in ("sarsa", "double_dqn")}


@pytest.mark.parametrize("condition", [c for c in CONDITIONS if not c.endswith("_none")])
def test_every_method_trains_on_lbf_instances_and_changes_what_is_learned(tmp_path, controls, condition):
    """Each method runs 300 steps on two LBF instances: evaluations at 0, 150, 300 with team returns in
    LBF's [0, 1], checkpoints that rebuild the same instance, and agents that differ from the same seed's
    run without exchange on some instance (the method acted: same instance, seed and exploration streams;
    advice needs a state the team-mate knows, which one of the two instances meets in 300 steps)."""
    run_dir = short_run(tmp_path, condition)
    learner, method = learner_and_method(condition)
    changed = []
    for map_seed in (3, 4):
        replica = run_dir / f"seed_0-map_{map_seed}"
        records = [r for r in read_metrics(replica) if "team_return" in r]
        assert [r["step"] for r in records] == [0, 150, 300]
        assert all(0.0 <= r["team_return"] <= 1.0 for r in records)
        team = load_team(replica)
        assert team.game.reset_seed == map_seed
        if method == "shared_id":  # the agent-id segment after LBF's own
            assert team.meta["obs_layout"][-1] == ["agent_id", 2]
        control = agent_tensors(controls[learner] / f"seed_0-map_{map_seed}")
        changed.append(
            any(
                set(a) != set(b) or any(a[k].shape != b[k].shape or not np.array_equal(a[k], b[k]) for k in a)
                for a, b in zip(agent_tensors(replica), control)
            )
        )
    assert any(changed), f"{condition} learned exactly what the run without exchange did"
