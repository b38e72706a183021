"""The transfer hook: load a source agent's checkpoint into the target agents of a fresh run.

The source is a path (:mod:`dqn_transfer.sources` finds or pretrains it); the mapping onto the
target's observation is by segment name (:mod:`dqn_transfer.transfer_mapping`): segments only the
target has get zero input weights, so at step 0 the transferred agents compute exactly the source's
Q-values.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from dqn_transfer.agents import BatchedDQN, Learner
from dqn_transfer.checkpoint import CheckpointError, check_compatible, load_agent_checkpoint, load_training_state
from dqn_transfer.config import TrainConfig
from dqn_transfer.enums import Algorithm
from dqn_transfer.envs.game import TreasureHuntGame
from dqn_transfer.run_dir import TRAINING_STATE_FILE
from dqn_transfer.transfer_mapping import (
    TransferError,
    plan_segment_mapping,
    transfer_dqn_tensors,
    transfer_tabular_tensors,
)

log = logging.getLogger("dqn_transfer.transfer")


def transfer_targets(config: TrainConfig, num_agents: int) -> list[int]:
    """The agents that receive the transfer (``transfer.targets``, default all), checked."""
    targets = list(range(num_agents)) if config.transfer.targets is None else list(config.transfer.targets)
    bad = [i for i in targets if not 0 <= i < num_agents]
    if bad:
        raise TransferError(f"transfer.targets {bad} out of range for {num_agents} agents")
    return targets


def apply_transfer(config: TrainConfig, learner: Learner, game: TreasureHuntGame, source: Path) -> dict[str, Any]:
    """Load ``source`` into the target agents; returns what the run records about its source."""
    transfer = config.transfer
    targets = transfer_targets(config, game.num_agents)
    tensors, meta = load_agent_checkpoint(source)
    algorithm = Algorithm(config.agent.algorithm)
    target_layout = game.obs_layout()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            check_compatible(meta, {"algorithm": algorithm.value, "num_actions": game.num_actions, "size": game.size})
            if algorithm.is_tabular:
                mapped = transfer_tabular_tensors(tensors, meta["obs_layout"], target_layout,
                                                  num_actions=game.num_actions)
            else:
                mapped = transfer_dqn_tensors(tensors, meta["obs_layout"], target_layout,
                                              list(config.agent.hidden), game.num_actions)
        except (CheckpointError, ValueError) as err:  # TransferError is a ValueError
            raise TransferError(f"transfer source {source}: {err}") from None
        except (KeyError, IndexError, TypeError) as err:  # a meta or tensor this format never writes
            raise TransferError(f"transfer source {source}: malformed checkpoint ({type(err).__name__}: {err})") from None
    for warning in caught:
        log.warning("transfer: %s", warning.message)
    for i in targets:
        learner.load_agent_tensors(i, mapped)
    if not transfer.reset_optimizer:
        if algorithm.is_tabular:
            raise TransferError("transfer.reset_optimizer=false needs a DQN learner (tabular learners have no optimizer)")
        if len(targets) != game.num_agents:  # Adam keeps one step count per stacked parameter
            raise TransferError("transfer.reset_optimizer=false needs every agent as a target "
                                f"(transfer.targets={targets}): the agents share Adam's step count")
        carry_optimizer_state(learner, source, meta, target_layout, targets)
    if transfer.freeze:  # indices were checked against agent.hidden by config.validate
        learner.freeze(transfer.freeze)
    log.info("transfer: agents %s start from %s (digest %s...)", targets, source, meta["digest"][:12])
    return {
        "source": str(source.resolve()),
        "digest": meta["digest"],
        "source_algorithm": meta.get("algorithm"),
        "source_obs_layout": meta["obs_layout"],
        "source_steps": meta.get("steps"),
        "pretrained": transfer.source is None,
        "targets": targets,
    }


def carry_optimizer_state(learner: BatchedDQN, source: Path, meta: dict[str, Any], target_layout,
                          targets: list[int]) -> None:
    """``transfer.reset_optimizer=false``: start the targets' Adam moments from the source's.

    The moments live in the source run's resume state beside the agent file; the first layer's rows
    are mapped by segment like its weights (zero for target-only segments).
    """
    state_path = source.parent / TRAINING_STATE_FILE
    if not state_path.exists():
        raise TransferError(f"transfer.reset_optimizer=false needs the source's optimizer state, but {state_path} "
                            "does not exist (share the run's whole checkpoints/ directory, or use reset_optimizer=true)")
    arrays, state_meta = load_training_state(state_path)
    if state_meta.get("counters", {}).get("step") != meta.get("steps") or state_meta.get("obs_layout") != meta["obs_layout"]:
        raise TransferError(f"{state_path} is not the resume state of {source.name} (other steps or obs layout); "
                            "use reset_optimizer=true")
    member = 0 if meta["network"].get("share_parameters") else int(meta["agent_index"])
    plan = plan_segment_mapping(meta["obs_layout"], target_layout)
    moments: dict[str, dict[str, np.ndarray]] = {}
    step = 0
    for layer in range(len(meta["network"]["hidden"]) + 1):
        for name in (f"weight_{layer}", f"bias_{layer}"):
            prefix = f"learner/optim.{name}."
            if prefix + "exp_avg" not in arrays:  # frozen in the source, or it never trained
                continue
            step = int(np.asarray(arrays[prefix + "step"]).reshape(-1)[0])
            moments[name] = {}
            for key in ("exp_avg", "exp_avg_sq"):
                value = arrays[prefix + key][member]
                if name == "weight_0":  # [in, out]: rows are observation columns
                    mapped = np.zeros((plan.target_dim, value.shape[1]), dtype=value.dtype)
                    mapped[plan.projection] = value[plan.source_columns]
                    value = mapped
                moments[name][key] = value
    for i in targets:
        learner.set_member_optimizer_state(i, moments, step)
