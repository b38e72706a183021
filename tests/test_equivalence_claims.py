"""The third edition's analysis (dqn_transfer.experiments.equivalence_claims) on synthetic runs whose answers
are worked out by hand: the normalised outcomes over the fixed horizon, a cell's outcomes and verdict, the
controls and the room."""

import pytest

from dqn_transfer.analysis.equivalence import Outcome
from dqn_transfer.envs import PettingZooGame
from dqn_transfer.evaluation.bounds import evaluate_bound
from dqn_transfer.experiments.equivalence_claims import (
    Verdict,
    failed_controls,
    family,
    final_score,
    normalised_auc,
    random_team_return,
    room,
    verdict,
)
from dqn_transfer.experiments.raw_data import RunData

STEPS = tuple(range(0, 16_501, 500))  # 0, 500, ..., 16,000 and one evaluation past the horizon
MAPS, SEEDS = 5, 3


def run(returns, optimum=180.0, map_seed=0, seed=0, name="run", **env) -> RunData:
    config = {"seed": seed, "total_steps": 16_000, "env": {"map_seed": map_seed, **env}}
    return RunData("cell", name, config, STEPS, {"team_return": tuple(returns)}, 0, optimum)


def test_the_normalised_outcomes_cover_the_horizon_after_step_0():
    # Random team -20, oracle 180: the return -20 + 200 s / 16,000 at step s scores s / 16,000. Steps 0 and
    # 16,500 hold 999, which must not count.
    returns = [999.0 if s in (0, 16_500) else -20.0 + 200.0 * s / 16_000 for s in STEPS]
    r = run(returns)
    assert normalised_auc(r, -20.0) == pytest.approx(sum(k / 32 for k in range(1, 33)) / 32)  # 0.515625
    assert final_score(r, -20.0) == pytest.approx(sum(k / 32 for k in range(26, 33)) / 7)  # 13,000..16,000: 29/32
    # Another game: its own return, 1 when all food is loaded.
    lbf = run([0.25] * len(STEPS), optimum=None, factory="dqn_transfer.envs.lbf:parallel_env")
    assert normalised_auc(lbf, 0.0) == pytest.approx(0.25)
    # One chest for two agents, no clean optimum: the chest's reward is the one; 60 over a random team of -40.
    one_chest = run([20.0] * len(STEPS), optimum=None, num_treasures=1, treasure_reward=100.0)
    assert normalised_auc(one_chest, -40.0) == pytest.approx(60.0 / 140.0)


def condition(score_of, name: str) -> list[RunData]:
    """Runs on MAPS x SEEDS whose normalised score is ``score_of(map, seed)`` at every evaluation."""
    return [
        run([score_of(m, s) * 100.0] * len(STEPS), optimum=100.0, map_seed=m, seed=s, name=name)
        for m in range(MAPS)
        for s in range(SEEDS)
    ]


def auc(r: RunData) -> float:
    return normalised_auc(r, 0.0)


RUNS = {
    "none": condition(lambda m, s: 0.5 + 0.05 * m - 0.01 * s, "none"),
    "useful": condition(lambda m, s: 0.6 + 0.05 * m - 0.01 * s, "useful"),  # +0.10 on every unit
    "negligible": condition(lambda m, s: 0.51 + 0.05 * m - 0.01 * s, "negligible"),  # +0.01 on every unit
    "harmful": condition(lambda m, s: 0.4 + 0.05 * m - 0.01 * s, "harmful"),  # -0.10
    # +0.2 on even maps, -0.16 on odd ones: mean +0.056 over 5 maps, far too spread to tell
    "noisy": condition(lambda m, s: 0.5 + 0.05 * m - 0.01 * s + (0.2 if m % 2 == 0 else -0.16), "noisy"),
}


def test_a_cells_outcomes_and_verdict():
    comparisons = family(RUNS, ["useful", "negligible", "harmful", "noisy"], auc)
    assert [c.outcome for c in comparisons] == [
        Outcome.better,
        Outcome.equivalent,
        Outcome.worse,
        Outcome.inconclusive,
    ]
    assert comparisons[0].contrast.mean == pytest.approx(0.10) and comparisons[0].contrast.n_maps == MAPS
    assert verdict(comparisons) is Verdict.supported
    assert verdict(comparisons[1:]) is Verdict.contradicted  # none better, one worse
    assert verdict(comparisons[1:2]) is Verdict.no_useful_effect
    assert verdict([comparisons[1], comparisons[3]]) is Verdict.inconclusive


def test_a_cell_is_validated_only_when_both_controls_come_out_as_they_must():
    runs = {**RUNS, "sham": RUNS["negligible"], "warm": RUNS["useful"]}
    assert failed_controls(family(runs, ["sham", "warm"], auc)) == []
    runs = {**RUNS, "sham": RUNS["useful"], "warm": RUNS["noisy"]}
    assert failed_controls(family(runs, ["sham", "warm"], auc)) == ["sham", "warm"]


def test_the_room_is_what_separates_none_from_the_oracle():
    # none scores 0.5 + 0.05 m - 0.01 s: its map means 0.49 .. 0.69, their mean 0.59, so the room is 0.41.
    assert room(RUNS["none"], auc).mean == pytest.approx(0.41)


# An agent beside its chest over a wall (tests/test_bounds.py): a random agent's return is worth 66.31.
BESIDE_THE_CHEST = {"layout": "0T\n##", "mode": "cooperative"}
LBF = {"factory": "dqn_transfer.envs.lbf:parallel_env", "kwargs": {"size": 8, "players": 2, "food": 2}, "map_seed": 3}


def test_the_random_team_is_played_again_on_each_runs_map_or_instance():
    def on(env: dict, seed: int = 0) -> RunData:
        return RunData("cell", "run", {"seed": seed, "env": env}, (500,), {"team_return": (0.0,)}, 0, None)

    beside = random_team_return(on(BESIDE_THE_CHEST))
    # 100 episodes of a return whose standard deviation is about 48: within 15 of 66.31 99.8% of the time.
    assert beside == pytest.approx(66.30859375, abs=15.0)
    assert random_team_return(on(BESIDE_THE_CHEST, seed=7)) == beside  # the map's, whatever the run's seed
    instance = random_team_return(on({**LBF, "fixed_start": True}))
    assert 0.0 <= instance <= 1.0  # LBF's normalised team return
    assert (
        instance
        == evaluate_bound(PettingZooGame(LBF["factory"], LBF["kwargs"], 3), "random", episodes=100, seed=0)[
            "team_return"
        ]
    )
    with pytest.raises(ValueError, match="oracle team walks a treasure hunt's map"):
        evaluate_bound(PettingZooGame(LBF["factory"], LBF["kwargs"], 3), "oracle", episodes=1, seed=0)
