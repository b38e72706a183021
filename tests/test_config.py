"""Every config option composes through Hydra; typos, wrong types and out-of-range values are refused."""

import json
import sys

import numpy as np
import pytest
from conftest import compose_config
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf
from omegaconf.errors import ValidationError

from dqn_transfer.agents import make_learner
from dqn_transfer.config import (
    AgentConfig,
    ConfigError,
    plain_yaml,
    to_plain,
    validate,
)
from dqn_transfer.config.help import group_options
from dqn_transfer.config.overrides import check_overrides
from dqn_transfer.enums import Algorithm, Fill, Mode


@pytest.mark.parametrize("env", ["simple", "complex"])
@pytest.mark.parametrize("mode", ["competitive", "cooperative", "deliberative"])
@pytest.mark.parametrize("agent", ["sarsa", "qlearning", "dqn", "double_dqn"])
@pytest.mark.parametrize("transfer", ["off", "on"])
def test_every_group_option_composes(env, mode, agent, transfer):
    config = compose_config(f"env={env}", f"mode={mode}", f"agent={agent}", f"transfer={transfer}")
    assert config.env.mode is Mode(mode)
    assert config.agent.algorithm is Algorithm(agent)
    assert config.transfer.enabled is (transfer == "on")
    validate(config)


# conf/experiment/tune/: the searches, and base, the protocol they share
TUNING_SEARCHES = [o for o in group_options("experiment") if o.startswith("tune/") and o != "tune/base"]


@pytest.mark.parametrize("search", TUNING_SEARCHES)
def test_a_tuning_search_without_the_optuna_sweeper_names_the_extra(search, monkeypatch):
    """Every search of conf/experiment/tune/ runs on Hydra's Optuna sweeper (its base picks it): without
    the plugin, choosing one is one line naming the extra, before Hydra's own multi-line error."""
    monkeypatch.setitem(sys.modules, "hydra_plugins.hydra_optuna_sweeper", None)  # as if not installed
    with pytest.raises(ConfigError) as refusal:
        check_overrides([f"experiment={search}"])
    assert str(refusal.value) == (
        f'experiment={search} (hydra/sweeper=optuna) needs its Hydra plugin: pip install "dqn_transfer[optuna]"'
    )


def test_defaults_are_the_documented_ones():
    config = compose_config()
    assert config.agent.algorithm is Algorithm.double_dqn
    assert config.env.size == 6 and config.env.mode is Mode.competitive
    assert config.transfer.enabled is False
    assert config.agent.hidden == [64, 64]


def test_the_schema_default_agent_is_the_command_lines():
    """One truth: `python train.py` with no `agent=` builds the learner `AgentConfig()` describes."""
    assert compose_config().agent == AgentConfig()
    assert AgentConfig().algorithm is Algorithm.double_dqn


def test_transfer_takes_an_offset_a_fill_and_a_source_agent_per_target():
    config = compose_config(
        "transfer=on", "transfer.offset=[2,1]", "transfer.fill=nearest", "transfer.source_agent=[1,0,1]"
    )
    assert config.transfer.offset == [2, 1] and config.transfer.fill is Fill.nearest
    assert config.transfer.source_agent == [1, 0, 1]
    validate(config)
    assert compose_config("transfer.source_agent=2").transfer.source_agent == 2


def test_mode_group_sets_the_env_mode_not_a_new_key():
    config = compose_config("mode=deliberative", "env=complex")
    assert config.env.mode is Mode.deliberative and config.env.size == 10


@pytest.mark.parametrize(
    "override",
    [
        "agent.learning_rate=0.1",  # typo of agent.lr
        "env.sise=8",
        "agent.gamma=high",  # wrong type
        "total_steps=many",
        "env.mode=telepathic",  # not a Mode
        "agent=ppo",  # no such group option
        "transfer.fill=far",  # not a Fill
    ],
)
def test_bad_overrides_are_refused(override):
    with pytest.raises((ConfigCompositionException, ValidationError)):
        compose_config(override)


@pytest.mark.parametrize(
    "override, message",
    [
        ("agent.gamma=1.5", "agent.gamma must be in \\[0, 1\\]"),
        ("agent.batch_size=0", "agent.batch_size must be >= 1"),
        ("total_steps=-5", "total_steps must be >= 0"),
        ("env.complexity=1.2", "env.complexity must be in \\[0, 1\\)"),
        ("agent.hidden=[]", "agent.hidden must be a non-empty list"),
        ("agent.tau=0", "agent.tau must be in \\(0, 1\\]"),
        ("env.max_steps=0", "env.max_steps must be >= 1"),
        ("transfer.exchange_tau=1.5", "transfer.exchange_tau must be in \\(0, 1\\]"),
        ("agent.lr=0", "agent.lr must be > 0"),
        ("transfer.freeze=[0]", "transfer.freeze=\\[0\\] .* needs transfer=on"),
        ("transfer.offset=[1]", "transfer.offset must be \\[row, col\\] with both >= 0, got \\[1\\]"),
        (
            "transfer.offset=[1,1]",
            "transfer.offset=\\[1, 1\\] / transfer.fill=zero place a source's map .* need transfer=on",
        ),
        ("transfer.offset=[0,-1]", "transfer.offset must be \\[row, col\\]"),
        ("transfer.source_agent=-1", "transfer.source_agent must be an agent index or a non-empty list"),
        ("transfer.source_agent=[0,x]", "transfer.source_agent must be"),
        ("transfer.source_agent=[]", "transfer.source_agent must be"),
        ("transfer.source_agent=true", "transfer.source_agent must be"),
    ],
)
def test_out_of_range_values_name_the_key(override, message):
    config = compose_config(override)
    with pytest.raises(ConfigError, match=message):
        validate(config)


def test_tabular_learners_refuse_network_only_options():
    config = compose_config("agent=sarsa", "transfer=on", "transfer.freeze=[0]")
    with pytest.raises(ConfigError, match="transfer.freeze applies to network layers"):
        validate(config)
    validate(compose_config("agent=sarsa", "transfer.exchange=best"))  # tables exchange too


@pytest.mark.parametrize(
    "option, algorithm",
    [
        ("dqn", Algorithm.dqn),
        ("double_dqn", Algorithm.double_dqn),
        ("sarsa", Algorithm.sarsa),
        ("qlearning", Algorithm.qlearning),
    ],
)
def test_the_command_line_and_the_python_api_build_the_same_learner(option, algorithm):
    """`agent=<option>` on the command line is the schema's defaults plus what the option says it
    changes (tabular: lr 0.1, alpha): the learner built from it is the one the Python API builds."""
    composed = compose_config(f"agent={option}").agent
    api = AgentConfig(algorithm=algorithm, **({"lr": 0.1} if algorithm.is_tabular else {}))
    assert composed == api
    layout, actions = [("position", 9)], 4
    a, b = (make_learner(hp, 2, layout, actions, seed=0) for hp in (composed, api))
    assert type(a) is type(b)
    # the keys each learner reads (docs/learners.md): tabular ones read only these three
    read = ["algorithm", "lr", "gamma"]
    if not algorithm.is_tabular:
        read += [
            "batch_size",
            "learning_starts",
            "train_freq",
            "gradient_steps",
            "target_update",
            "tau",
            "hidden",
            "max_grad_norm",
            "share_parameters",
        ]
    for name in read:
        value = getattr(api, name)
        assert getattr(a, name) == getattr(b, name) == (value.value if name == "algorithm" else value), name
    for i in range(2):  # and the same seed gives the same starting weights or tables
        ta, tb = a.agent_tensors(i), b.agent_tensors(i)
        assert ta.keys() == tb.keys() and all(np.array_equal(ta[k], tb[k]) for k in ta), i


LAYOUT_5X5 = "0...T\n.....\n..X..\n.....\n1...T"


@pytest.mark.parametrize("group", ["env=simple", "env=complex", "env=study/m4"])
def test_a_layout_warns_only_about_generation_keys_the_user_set(tmp_path, group):
    """The documented warm start (``env.layout_file=shared/team/map.txt``) once warned ``ignoring
    generation parameters: map_seed=6``: env=simple's own map seed, which nobody set. Only a key the
    user set (one that differs from the env option's) is named."""
    import warnings

    from dqn_transfer.training.plan import plan_run

    (tmp_path / "map.txt").write_text(LAYOUT_5X5)
    layout = f"env.layout_file={tmp_path / 'map.txt'}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plan = plan_run(compose_config(group, layout))
    assert plan.replicas[0].grid_map.size == 5
    with pytest.warns(UserWarning, match="a layout fixes the map") as caught:
        plan_run(compose_config(group, layout, "env.size=9", "env.map_seed=3"))
    [message] = [str(w.message) for w in caught]
    assert message.endswith("size=9 (layout: 5), map_seed=3 (a layout is not generated)"), message


@pytest.mark.parametrize(
    "overrides",
    [
        (),
        ("agent=sarsa", "mode=deliberative", "env=complex", "transfer=on", "agent.lr=1"),
        ("curriculum=nested", "agent=qlearning", "replicas.seeds=3", "logger=[tensorboard,csv]"),
        ("experiment=hypothesis", "transfer.exchange=best", "transfer.freeze=[0]"),
        ("experiment=claim2", "env.layout='0.T.X1'", "env.max_steps=7"),
        ("env=lbf", "agent=dqn", "env.kwargs.sight=2"),
    ],
)
def test_plain_configs_and_their_yaml_are_omegaconfs(overrides):
    """to_plain reads the dataclasses directly; it must give exactly what OmegaConf's structured config
    gives (run hashes, checkpoint meta and the replicas' config.yaml are made of it)."""
    config = compose_config(*(o if not o.startswith("env.kwargs.") else "+" + o for o in overrides))
    for part in (config, config.agent, config.env, config.transfer):
        expected = OmegaConf.to_container(OmegaConf.structured(part), resolve=True, enum_to_str=True)
        assert to_plain(part) == expected
        assert json.dumps(to_plain(part)) == json.dumps(expected)  # types too: 1.0 stays a float
    assert OmegaConf.to_yaml(to_plain(config)) == OmegaConf.to_yaml(OmegaConf.structured(config))
    assert plain_yaml(to_plain(config)) == OmegaConf.to_yaml(OmegaConf.structured(config))
