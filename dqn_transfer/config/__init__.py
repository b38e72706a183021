"""The run's configuration: typed schemas (:mod:`.schema`) and the ``--help`` page (:mod:`.help`).

The YAML options of each config group live in ``conf/`` at the repository's root (installed as the package
``dqn_transfer.conf``, so it is found from any directory); the schemas give every key its type and default.
"""

from dqn_transfer.config.schema import (
    CONFIG_DIR,
    SB3_NAMES,
    AgentConfig,
    ConfigError,
    CurriculumConfig,
    EnvConfig,
    ReplicasConfig,
    StageConfig,
    TrainConfig,
    TransferConfig,
    plain_yaml,
    register_configs,
    replica_configs,
    to_plain,
    validate,
)

__all__ = [
    "CONFIG_DIR",
    "SB3_NAMES",
    "AgentConfig",
    "ConfigError",
    "CurriculumConfig",
    "EnvConfig",
    "ReplicasConfig",
    "StageConfig",
    "TrainConfig",
    "TransferConfig",
    "register_configs",
    "replica_configs",
    "plain_yaml",
    "to_plain",
    "validate",
]
