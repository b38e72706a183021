"""Tabular SARSA / Q-learning updates worked out by hand (alpha = 0.5, gamma = 0.9)."""

import numpy as np
import pytest

from dqn_transfer.agents import Experience, TabularLearner, Transition
from dqn_transfer.agents.base import Acting
from dqn_transfer.agents.state_index import DenseIndex, MetOrderIndex
from dqn_transfer.agents.visit_exchange import AdviceRules
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm, Mode
from dqn_transfer.envs.game import make_game
from dqn_transfer.envs.observation_code import observation_code
from dqn_transfer.evaluation.rollout import evaluate
from dqn_transfer.exchange.best import exchange_best
from dqn_transfer.exchange.shared_replay import exchange_replay

LAYOUT = [("position", 2)]
S0 = np.array([1.0, 0.0], dtype=np.float32)
S1 = np.array([0.0, 1.0], dtype=np.float32)
ALL_LIVE = np.ones(3, dtype=bool)


def tabular(
    algorithm: str, num_agents: int, layout=LAYOUT, actions: int = 2, lr: float = 0.5, seed: int = 0
) -> TabularLearner:
    return TabularLearner(
        num_agents, layout, actions, AgentConfig(algorithm=Algorithm(algorithm), lr=lr, gamma=0.9), seed=seed
    )


def learner(algorithm: str, num_agents: int = 3, seed: int = 0) -> TabularLearner:
    agent = tabular(algorithm, num_agents, seed=seed)
    for i in range(num_agents):  # every agent starts knowing Q(S1) = [2, 4]; S0 unseen (0, 0)
        table = {"keys": S1[None], "values": np.array([[2.0, 4.0]], dtype=np.float32)}
        agent.load_agent_tensors(i, table)
    return agent


def flags(*rows: str) -> tuple[np.ndarray, np.ndarray]:
    """Per agent: "" (step continues), "term" or "trunc"."""
    return np.array([r == "term" for r in rows]), np.array([r == "trunc" for r in rows])


@pytest.mark.parametrize("algorithm", ["sarsa", "qlearning"])
def test_one_update_normal_terminated_truncated(algorithm):
    agent = learner(algorithm)
    agent.act(np.stack([S0, S0, S0]), ALL_LIVE, epsilon=0.0)  # SARSA's a' uses this epsilon: greedy
    terminated, truncated = flags("", "term", "trunc")
    out = agent.update(
        Transition(
            obs=np.stack([S0, S0, S0]),
            actions=np.array([0, 1, 0]),
            rewards=np.array([1.0, 1.0, 0.0]),
            next_obs=np.stack([S1, S1, S1]),
            terminated=terminated,
            truncated=truncated,
            live=ALL_LIVE,
        ),
        step=1,
    )
    # agent 0: y = 1 + 0.9 * Q(S1, a'=argmax=1) = 1 + 0.9 * 4 = 4.6 ; Q(S0,0) = 0 + 0.5 * 4.6 = 2.3
    # agent 1: terminated, y = 1                               ; Q(S0,1) = 0 + 0.5 * 1   = 0.5
    # agent 2: truncated still bootstraps, y = 0 + 0.9 * 4 = 3.6 ; Q(S0,0) = 0 + 0.5 * 3.6 = 1.8
    assert agent.agent_q_values(0, S0).tolist() == pytest.approx([2.3, 0.0])
    assert agent.agent_q_values(1, S0).tolist() == pytest.approx([0.0, 0.5])
    assert agent.agent_q_values(2, S0).tolist() == pytest.approx([1.8, 0.0])
    assert agent.agent_q_values(0, S1).tolist() == [2.0, 4.0]  # next state untouched
    np.testing.assert_allclose(out.q_mean, [0.0, 0.0, 0.0])  # Q(s, a) before the update
    # Huber of the TD errors 4.6, 1.0, 3.6: |d| - 0.5 for |d| >= 1
    np.testing.assert_allclose(out.td_loss, [4.1, 0.5, 3.1], rtol=1e-6)
    # SARSA caches a' only where the episode goes on.
    if algorithm == "sarsa":
        np.testing.assert_array_equal(agent.next_action, [1, -1, -1])


def test_qlearning_bootstraps_from_the_max_not_the_played_action():
    agent = learner("qlearning", num_agents=1)
    agent.act(S0[None], np.ones(1, bool), epsilon=1.0)  # fully random play
    agent.update(Transition(S0[None], np.array([0]), np.array([1.0]), S1[None], *flags(""), np.ones(1, bool)), step=1)
    # y = 1 + 0.9 * max(2, 4) = 4.6 whatever is played next ; Q(S0,0) = 0.5 * 4.6
    assert agent.agent_q_values(0, S0)[0] == pytest.approx(2.3)


def test_sarsa_bootstraps_from_the_cached_next_action_and_plays_it():
    k = 8
    agent = learner("sarsa", num_agents=k, seed=3)
    live = np.ones(k, bool)
    agent.act(np.stack([S0] * k), live, epsilon=1.0)  # random a': agents end up with different ones
    agent.update(
        Transition(
            np.stack([S0] * k),
            np.zeros(k, np.int64),
            np.ones(k),
            np.stack([S1] * k),
            np.zeros(k, bool),
            np.zeros(k, bool),
            live,
        ),
        step=1,
    )
    cached = agent.next_action.copy()
    assert set(cached.tolist()) == {0, 1}
    for i, a_next in enumerate(cached):
        # a' = 0: y = 1 + 0.9 * 2 = 2.8 -> Q = 1.4 ; a' = 1: y = 1 + 0.9 * 4 = 4.6 -> Q = 2.3
        assert agent.agent_q_values(i, S0)[0] == pytest.approx({0: 1.4, 1: 2.3}[int(a_next)])
    # The next act on S1 plays exactly the cached a' (even with epsilon = 1), then forgets it.
    np.testing.assert_array_equal(agent.act(np.stack([S1] * k), live, epsilon=1.0), cached)
    np.testing.assert_array_equal(agent.next_action, -1)


def test_sarsa_cache_is_ignored_for_another_observation_and_in_greedy_mode():
    agent = learner("sarsa", num_agents=1)
    agent.load_agent_tensors(0, {"keys": np.stack([S0, S1]), "values": np.array([[0.0, 5.0], [2.0, 4.0]], np.float32)})
    agent.next_action[0], agent.next_state[0] = 0, agent.state_ids(S1[None], np.array([0]))[0]  # "play 0 in S1"
    # Greedy evaluation: argmax Q(S1) = 1, the cache is not consulted and survives.
    assert agent.greedy(S1[None], np.ones(1, bool))[0] == 1
    assert agent.next_action[0] == 0
    # A different observation (e.g. after a reset) does not use the cache: greedy on S0 plays 1, and the
    # stale cache is dropped.
    assert agent.act(S0[None], np.ones(1, bool), epsilon=0.0)[0] == 1
    assert agent.next_action[0] == -1


def test_dead_agents_are_not_updated_and_get_nan():
    agent = learner("qlearning")
    live = np.array([True, False, True])
    out = agent.update(
        Transition(
            np.stack([S0] * 3),
            np.zeros(3, np.int64),
            np.ones(3),
            np.stack([S1] * 3),
            *flags("term", "term", "term"),
            live,
        ),
        step=1,
    )
    assert np.isnan(out.td_loss[1]) and np.isnan(out.q_mean[1])
    assert len(agent.agent_tensors(1)["keys"]) == 1 and len(agent.agent_tensors(0)["keys"]) == 2


def test_fallback_initialises_unseen_entries_and_round_trips():
    agent = tabular("qlearning", 1)
    # Source table keyed on the target's column 1 only: key [1] -> (5, 7).
    agent.add_fallback(np.array([[1.0]], np.float32), np.array([[5.0, 7.0]], np.float32), np.array([1]))
    assert agent.agent_q_values(0, S1).tolist() == [5.0, 7.0]  # S1[[1]] = [1] is in the fallback
    assert agent.agent_q_values(0, S0).tolist() == [0.0, 0.0]  # S0[[1]] = [0] is not: 0
    agent.update(
        Transition(S1[None], np.array([0]), np.array([0.0]), S0[None], *flags("term"), np.ones(1, bool)), step=1
    )
    # Entry created from the fallback, then updated: y = 0 ; Q(S1,0) = 5 + 0.5 * (0 - 5) = 2.5
    assert agent.agent_q_values(0, S1).tolist() == [2.5, 7.0]

    tensors = agent.agent_tensors(0)
    assert tensors["fallback_projection"].dtype == np.int64
    assert tensors["keys"].dtype == tensors["values"].dtype == np.float32
    clone = tabular("qlearning", 1, seed=1)
    clone.load_agent_tensors(0, tensors)
    for obs in (S0, S1, np.array([1.0, 1.0], np.float32)):
        assert clone.agent_q_values(0, obs).tolist() == agent.agent_q_values(0, obs).tolist()


def test_training_state_round_trip_continues_identically():
    rng = np.random.default_rng(5)
    states = np.eye(4, dtype=np.float32)
    inputs = [
        (rng.integers(4, size=2), rng.integers(4, size=2), rng.normal(size=2), rng.random(2) < 0.2) for _ in range(60)
    ]
    layout = [("position", 4)]

    def run(agent, steps):
        for s, s_next, r, done in steps:
            actions = agent.act(states[s], np.ones(2, bool), epsilon=0.3)
            agent.update(
                Transition(states[s], actions, r, states[s_next], done, np.zeros(2, bool), np.ones(2, bool)), 0
            )

    a = tabular("sarsa", 2, layout, 4, lr=0.1, seed=0)
    run(a, inputs[:30])
    b = tabular("sarsa", 2, layout, 4, lr=0.1, seed=0)  # the seed is the run's; the state holds the counters
    for i in range(2):
        b.load_agent_tensors(i, a.agent_tensors(i))
    b.load_training_state(*a.training_state())
    run(a, inputs[30:])
    run(b, inputs[30:])
    for i in range(2):
        for name, tensor in a.agent_tensors(i).items():
            assert np.array_equal(tensor, b.agent_tensors(i)[name])


def test_tabular_learner_refuses_a_dqn_config():
    with pytest.raises(ValueError, match="trains sarsa or qlearning, not dqn"):
        TabularLearner(1, LAYOUT, 2, AgentConfig(algorithm=Algorithm.dqn))


def test_q_values_of_the_team_are_each_agents_own():
    agent = learner("qlearning")
    agent.update(
        Transition(
            np.stack([S0] * 3),
            np.array([0, 1, 0]),
            np.ones(3),
            np.stack([S1] * 3),
            *flags("term", "term", "term"),
            ALL_LIVE,
        ),
        step=1,
    )
    # Each agent: y = 1 (terminated), Q(S0, a) = 0.5 * 1 for its own a; S1 = [2, 4] everywhere.
    np.testing.assert_allclose(agent.q_values(np.stack([S0, S0, S1])), [[0.5, 0.0], [0.0, 0.5], [2.0, 4.0]])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_untrained_agents_evaluate_alike_whatever_their_observation_encodes(seed):
    """Greedy ties (every state of an untrained table) are drawn from the evaluation episode's generator,
    not from the observation: with one agent, the three modes differ only in what the observation
    holds (deliberative adds the coordinator's assignment), so their untrained step-0 evaluations must
    be the same episodes. A rule keyed on the observation's bytes made them differ."""
    layout = "0....\n.....\n..T..\n.....\nX...."
    results = []
    for mode in Mode:
        game = make_game(layout=layout, mode=mode)
        learner = TabularLearner(
            1, game.obs_layout(), game.num_actions, AgentConfig(algorithm=Algorithm.sarsa), seed=seed
        )
        counters = {stream: count.copy() for stream, count in learner.counters.items()}
        results.append(evaluate(learner, game, episodes=5, seed=seed, step=0))
        assert learner.counters == counters  # evaluation draws none of the learner's numbers
    assert results[0] == results[1] == results[2]
    assert len({game.obs_dim for game in [make_game(layout=layout, mode=m) for m in Mode]}) == 2


def test_greedy_ties_go_to_a_drawn_best_action_and_never_to_a_worse_one():
    learner = TabularLearner(1, [("position", 2)], 4, AgentConfig(algorithm=Algorithm.qlearning), seed=0)
    obs = np.array([[1.0, 0.0]], dtype=np.float32)
    learner.load_agent_tensors(0, {"keys": obs, "values": np.array([[5.0, 1.0, 5.0, 5.0]], dtype=np.float32)})
    live = np.array([True])
    ties = np.random.default_rng(7)
    drawn = {int(learner.greedy(obs, live, ties)[0]) for _ in range(60)}
    assert drawn == {0, 2, 3}  # each best action, in turn; never action 1
    assert learner.greedy(obs, live)[0] == 0  # without a generator: the first best


def test_exchange_best_moves_every_other_table_towards_the_best_agents_over_both_tables_states():
    learner = TabularLearner(3, [("position", 2)], 4, AgentConfig(algorithm=Algorithm.qlearning), seed=0)
    s1, s2 = np.array([1.0, 0.0], np.float32), np.array([0.0, 1.0], np.float32)
    learner.load_agent_tensors(0, {"keys": s1[None], "values": np.array([[4.0, 0, 0, 0]], np.float32)})
    best = {"keys": np.stack([s2, s1]), "values": np.array([[8.0, 0, 0, 0], [2.0, 2, 0, 0]], np.float32)}
    learner.load_agent_tensors(1, best)
    window_returns = np.array([[0.0, 10.0, 1.0], [2.0, 6.0, 1.0]])  # agent 1 has the best mean, 8
    assert exchange_best(learner, window_returns, tau=0.5) == 1
    # Agent 0's table: its own s1 first, then s2 (new to it, in the best agent's order).
    table0 = learner.agent_tensors(0)
    np.testing.assert_array_equal(table0["keys"], np.stack([s1, s2]))
    np.testing.assert_array_equal(table0["values"], [[3, 1, 0, 0], [4, 0, 0, 0]])  # (4 + 2) / 2; 0 -> halfway to 8
    table2 = learner.agent_tensors(2)  # agent 2 held nothing: both of the best agent's states, halfway
    np.testing.assert_array_equal(table2["keys"], np.stack([s2, s1]))
    np.testing.assert_array_equal(table2["values"], [[4, 0, 0, 0], [1, 1, 0, 0]])
    after = learner.agent_tensors(1)
    assert all(np.array_equal(after[name], best[name]) for name in best)  # the best agent is unchanged


@pytest.mark.parametrize("algorithm", [Algorithm.qlearning, Algorithm.sarsa])
def test_exchange_replay_updates_each_table_on_its_team_mates_transitions(algorithm):
    learner = TabularLearner(2, [("position", 2)], 4, AgentConfig(algorithm=algorithm, lr=0.5, gamma=0.9), seed=0)
    s1, s2 = np.array([1.0, 0.0], np.float32), np.array([0.0, 1.0], np.float32)
    learner.load_agent_tensors(1, {"keys": s2[None], "values": np.array([[0.0, 5.0, 5.0, 5.0]], np.float32)})
    # agent 0 moved s1 -> s2 with action 2 and reward 1; agent 1 was already done
    step = Transition(
        np.stack([s1, s1]),
        np.array([2, 0]),
        np.array([1.0, 0.0], np.float32),
        np.stack([s2, s2]),
        np.array([False, False]),
        np.array([False, False]),
        np.array([True, False]),
    )
    exchange_replay(learner, [step], [np.array([False, False])])
    # agent 1: Q(s1, 2) = 0 + 0.5 * (1 + 0.9 * Q(s2, a') - 0); Q-learning a' = argmax (5), SARSA a' is
    # epsilon-greedy with epsilon 0 (no act yet): a greedy one, also 5
    np.testing.assert_allclose(learner.agent_q_values(1, s1), [0, 0, 2.75, 0])
    assert len(learner.agent_tensors(0)["keys"]) == 0  # agent 0 learns only from team-mates (none were live)
    assert (learner.next_action == -1).all()  # SARSA's cached next action belongs to the agent's own steps


def first_seen_ids(stream: list[tuple[np.ndarray, np.ndarray]], replica_of_row: np.ndarray) -> list[np.ndarray]:
    """Each lookup's ids numbered by hand: per replica, observations in the order first met."""
    seen: list[dict[bytes, int]] = [{} for _ in range(int(replica_of_row.max()) + 1)]
    expected = []
    for obs, rows in stream:
        ids = []
        for row, o in zip(rows, obs):
            index = seen[replica_of_row[row]]
            ids.append(index.setdefault(o.tobytes(), len(index)))
        expected.append(np.array(ids))
    return expected


@pytest.mark.parametrize("collide", [False, True])
def test_state_ids_number_each_replicas_observations_in_the_order_first_met(monkeypatch, collide):
    """Ids are found by hash, checked against the stored observation: with every hash equal (all
    observations collide) the ids are still the first-seen numbering."""
    if collide:
        monkeypatch.setattr(
            "dqn_transfer.agents.state_index.observation_hashes", lambda bits, replicas: np.zeros(len(bits), np.uint64)
        )
    agents, replicas = 2, 3
    table = TabularLearner(agents, [("cell", 3)], 2, AgentConfig(algorithm=Algorithm.sarsa), seed=list(range(replicas)))
    rng = np.random.default_rng(0)
    values = np.array([0.0, -0.0, 1.0, 0.5], dtype=np.float32)  # -0.0 and 0.0: different bits, different states
    stream = []
    for _ in range(300):  # lookups of all rows, of one replica's rows, of a few rows with repeats
        rows = [np.arange(6), np.arange(2, 4), rng.integers(0, 6, size=4)][rng.integers(3)]
        stream.append((values[rng.integers(0, 4, size=(len(rows), 3))], np.asarray(rows)))
    got = [table.state_ids(obs, rows) for obs, rows in stream]
    for g, e in zip(got, first_seen_ids(stream, table.row_replica)):
        np.testing.assert_array_equal(g, e)
    assert table.index.num_states.tolist() == [64, 64, 64]  # all 4^3 observations met, in every replica


def learn_from_one_at_a_time(table: TabularLearner, i: int, experience) -> None:
    """The statement learn_from computes faster: one ``_learn`` per transition, each with its own draws."""
    rows, replica = np.array([i]), int(table.row_replica[i])
    for n in range(len(experience.obs)):
        draws = table._draws("learn_from", rows)
        table._advance("learn_from", replica)
        table._learn(
            rows,
            experience.obs[n][None],
            np.array([experience.actions[n]]),
            np.asarray(experience.rewards, dtype=np.float32)[n : n + 1],
            experience.next_obs[n][None],
            np.array([experience.terminated[n]]),
            cache=np.array([False]),
            draws=draws,
        )


@pytest.mark.parametrize("algorithm", ["sarsa", "qlearning"])
def test_learning_from_team_mates_is_one_update_per_transition_in_order(algorithm):
    """Few states, so later transitions bootstrap from entries earlier ones changed; a fallback gives
    unseen states start values; replica 1's agent 2 learns, replica 0 is untouched."""
    tables = [tabular(algorithm, 3, layout=[("cell", 2)], actions=3, seed=[4, 9]) for _ in range(2)]
    rng = np.random.default_rng(1)
    cells = np.array([[x, y] for x in range(3) for y in range(3)], dtype=np.float32)
    for table in tables:
        table.add_fallback(cells[:4], rng.normal(size=(4, 3)).astype(np.float32), np.array([0, 1]), agent=5)
        table.epsilon[:] = 0.3  # SARSA's a' explores
        table.next_action[:] = 1  # a cached action the update must clear
        rng = np.random.default_rng(1)  # both tables the same
    rng = np.random.default_rng(2)
    for _ in range(3):  # three windows, so the draw counters and entry order carry on
        size = 200
        experience = Experience(
            cells[rng.integers(0, 9, size)],
            rng.integers(0, 3, size),
            rng.normal(size=size).astype(np.float32),
            cells[rng.integers(0, 9, size)],
            rng.random(size) < 0.1,
        )
        tables[0].learn_from(5, experience)
        learn_from_one_at_a_time(tables[1], 5, experience)
    fast, reference = tables
    assert np.array_equal(fast.q.view(np.uint32), reference.q.view(np.uint32))  # bit for bit
    assert np.array_equal(fast.entry_order, reference.entry_order) and fast.num_entries == reference.num_entries
    assert np.array_equal(fast.index.num_states, reference.index.num_states)
    assert np.array_equal(fast.index.state_keys, reference.index.state_keys)
    assert fast.counters["learn_from"].tolist() == reference.counters["learn_from"].tolist() == [0, 600]
    assert np.array_equal(fast.next_action, reference.next_action) and fast.next_action[5] == -1
    for i in range(6):
        for name, array in fast.agent_tensors(i).items():
            assert np.array_equal(array, reference.agent_tensors(i)[name]), (i, name)


def test_best_actions_of_stacked_observations_are_one_lookup_of_the_one_at_a_time_answers():
    """The tables answer E observations per row in one lookup: the same actions as E calls of
    best_actions (Acting's own loop), and the same states numbered in the same order."""
    tables = [tabular("sarsa", 2, layout=[("cell", 2)], actions=3, seed=[1, 2, 3]) for _ in range(2)]
    rng = np.random.default_rng(3)
    cells = np.array([[x, y] for x in range(3) for y in range(3)], dtype=np.float32)
    known = {"keys": cells[:5], "values": rng.integers(0, 3, size=(5, 3)).astype(np.float32)}  # with ties
    for table in tables:
        for i in range(6):
            table.load_agent_tensors(i, known)
    for _ in range(3):
        obs = cells[rng.integers(0, 9, size=(4, 6))]  # E = 4 observations for each of the 6 rows
        fast, reference = tables[0].best_actions_stacked(obs), Acting.best_actions_stacked(tables[1], obs)
        assert fast.shape == (4, 6, 3) and np.array_equal(fast, reference)
    assert np.array_equal(tables[0].index.num_states, tables[1].index.num_states)
    assert np.array_equal(tables[0].index.state_keys, tables[1].index.state_keys)


def dense_and_met_order(algorithm: str, games: list, seeds: list[int]) -> tuple[TabularLearner, TabularLearner]:
    """The same learner twice: with the games' observation code (dense tables), and without."""
    first = games[0]
    hp = AgentConfig(algorithm=Algorithm(algorithm), lr=0.3, gamma=0.9)
    code = observation_code(games)
    pair = tuple(
        TabularLearner(first.num_agents, first.obs_layout(), first.num_actions, hp, seed=seeds, code=c)
        for c in (code, None)
    )
    assert isinstance(pair[0].index, DenseIndex) and isinstance(pair[1].index, MetOrderIndex)
    return pair


@pytest.mark.parametrize(("algorithm", "mode"), [("sarsa", "deliberative"), ("qlearning", "competitive")])
def test_dense_tables_learn_exactly_what_the_met_order_index_learns(algorithm, mode):
    """Two replicas on two maps play, learn, exchange (best, confidence, team-mates' transitions) and
    take advice, from a fallback table: actions, statistics, tables and training state bit for bit."""
    games = [
        make_game(size=5, num_treasures=2, num_traps=1, num_agents=3, mode=mode, view_radius=1, map_seed=s)
        for s in (0, 3)
    ]
    dense, met = dense_and_met_order(algorithm, games, [7, 8])
    cells = games[0].position_codes()
    fallback = (
        cells,
        np.random.default_rng(0).normal(size=(len(cells), 4)).astype(np.float32),
        np.arange(len(cells[0])),
    )
    for learner in (dense, met):
        learner.add_fallback(*fallback, agent=4)
        learner.start_advice(AdviceRules(ask_below=2, answer_from=3, budget=50))
    rngs = [np.random.default_rng(r) for r in range(2)]
    obs = np.concatenate([game.reset(rng) for game, rng in zip(games, rngs)])
    experience: list = []
    for step in range(1, 400):
        live = np.concatenate([game.live for game in games])
        actions = dense.act(obs, live, epsilon=0.3)
        np.testing.assert_array_equal(actions, met.act(obs, live, epsilon=0.3))
        outcomes = [game.step(a) for game, a in zip(games, actions.reshape(2, -1))]
        joined = [np.concatenate(field) for field in zip(*(o[:4] for o in outcomes))]
        transition = Transition(obs, actions, joined[1], joined[0], joined[2], joined[3], live)
        for a, b in zip(dense.update(transition, step), met.update(transition, step)):
            np.testing.assert_array_equal(a, b)
        experience.append(transition)
        obs = joined[0]
        for r, (game, rng) in enumerate(zip(games, rngs)):
            if game.done:
                obs[r * 3 : (r + 1) * 3] = game.reset(rng)
        if step % 50 == 0:
            shared = Experience(*(np.stack([t[f][1] for t in experience]) for f in (0, 1, 2, 3, 4)))
            for learner in (dense, met):
                learner.soft_copy_best(0, 0.5, replica=1)
                learner.merge_confident(0.5, replica=0)
                learner.learn_from(2, shared)
            experience.clear()
    for row in range(6):
        mine, theirs = dense.agent_tensors(row), met.agent_tensors(row)
        assert mine.keys() == theirs.keys()
        for name in mine:
            np.testing.assert_array_equal(mine[name], theirs[name])
    for replica in range(2):
        (arrays, meta), (their_arrays, their_meta) = dense.training_state(replica), met.training_state(replica)
        assert meta == their_meta and arrays.keys() == their_arrays.keys()
        for name in arrays:
            np.testing.assert_array_equal(arrays[name], their_arrays[name])


def test_checkpoints_of_either_index_load_into_the_other():
    """A met-order checkpoint (today's) loads into dense tables and back, values and visits intact."""
    games = [make_game(size=5, num_treasures=2, num_traps=1, num_agents=2)]
    dense, met = dense_and_met_order("sarsa", games, [1])
    rng = np.random.default_rng(0)
    obs = games[0].reset(rng)
    for step in range(1, 60):
        actions = met.act(obs, games[0].live, epsilon=0.5)
        out = games[0].step(actions)
        met.update(Transition(obs, actions, out.rewards, out.obs, out.terminated, out.truncated, out.live | True), step)
        obs = out.obs if not games[0].done else games[0].reset(rng)
    restored, _ = dense_and_met_order("sarsa", games, [1])
    for source, target in ((met, dense), (dense, restored)):
        for i in range(2):
            target.load_agent_tensors(i, source.agent_tensors(i))
        target.load_training_state(*source.training_state())
    for learner in (dense, restored):
        for i in range(2):
            for name, array in met.agent_tensors(i).items():
                np.testing.assert_array_equal(learner.agent_tensors(i)[name], array)
        for name, array in met.training_state()[0].items():
            np.testing.assert_array_equal(learner.training_state()[0][name], array)


def test_dense_tables_refuse_a_key_that_is_no_observation_of_the_game():
    game = make_game(size=5, num_treasures=2, num_traps=1, num_agents=2)
    dense, _ = dense_and_met_order("qlearning", [game], [0])
    key = np.zeros((1, game.obs_dim), dtype=np.float32)  # on no cell
    with pytest.raises(ValueError, match="is no observation of this game"):
        dense.load_agent_tensors(0, {"keys": key, "values": np.ones((1, 4), dtype=np.float32)})


def test_dense_tables_start_every_state_from_the_fallback_at_once():
    """A fallback keyed on the position: every state of cell c starts at [c, 0, 0, 0] (ids are
    ``cell * 2**chests + beliefs`` in cooperative mode)."""
    game = make_game(size=5, num_treasures=2, num_traps=1, num_agents=2)
    dense, _ = dense_and_met_order("sarsa", [game], [0])
    cells = game.position_codes()
    values = np.zeros((25, 4), dtype=np.float32)
    values[:, 0] = np.arange(25)
    dense.add_fallback(cells, values, np.arange(25), agent=1)
    np.testing.assert_array_equal(dense.q[1, :, 0], np.arange(100) // 4)
    assert not dense.q[0].any()  # agent 0 has no fallback


class _HugeCode:
    num_ids = 10**9

    def encode(self, obs, replicas):
        raise AssertionError("never asked")

    def decode(self, replica, ids):
        raise AssertionError("never asked")


def test_a_code_whose_tables_would_not_fit_keeps_the_met_order_index():
    learner = TabularLearner(2, LAYOUT, 2, AgentConfig(algorithm=Algorithm.sarsa), code=_HugeCode())
    assert isinstance(learner.index, MetOrderIndex) and learner.q.shape[1] < 1000
