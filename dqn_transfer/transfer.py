"""``transfer=on``: start agents from a pretrained agent instead of random weights (DESIGN §6).

Where the source comes from:
- ``transfer.source`` is a checkpoint file, or a run directory (then ``transfer.source_agent``);
- unset, a source agent is pretrained on the source task — ``TreasureHunt-v0``, the single-agent MDP
  of the same map — for ``transfer.pretrain_steps`` and cached under
  ``outputs/pretrained/<hash of the source config>/``, so the next run with the same source config
  reuses it.  A file lock makes parallel sweep jobs pretrain it once.

How it maps: by observation segment name (:mod:`dqn_transfer.transfer_mapping`); segments only the
target has get zero input weights, so at step 0 the transferred agents compute exactly the source's
Q-values.  Also here: the team knowledge exchange run during training (``transfer.exchange``).
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import logging
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from dqn_transfer.checkpoint import (
    CheckpointError,
    check_compatible,
    find_checkpoints,
    load_agent_checkpoint,
    load_training_state,
)
from dqn_transfer.config import TABULAR, Algorithm, TrainConfig, TransferConfig
from dqn_transfer.transfer_mapping import (
    TransferError,
    plan_segment_mapping,
    transfer_dqn_tensors,
    transfer_tabular_tensors,
)

log = logging.getLogger("dqn_transfer.transfer")

# What defines a pretrained source: the map, the source task's dynamics and the learner.
_SOURCE_ENV_KEYS = ("size", "num_treasures", "num_traps", "num_agents", "complexity", "map_seed", "layout",
                    "layout_file", "max_steps", "obs_encoding", "view_radius", "treasure_reward",
                    "trap_reward", "step_reward")


def source_config(config: TrainConfig) -> TrainConfig:
    """The config of the source-task pretraining run: same map and learner, no transfer."""
    pretrain_steps = config.transfer.pretrain_steps
    return dataclasses.replace(
        config,
        transfer=TransferConfig(),
        total_steps=pretrain_steps,
        eval_every=max(1, pretrain_steps // 10),
        checkpoint_every=max(1, pretrain_steps // 4),
        resume=False,
    )


def source_hash(plain: dict[str, Any], layout: str) -> str:
    """Hash of everything that shapes the pretrained source; the map enters by its actual layout."""
    env = {key: plain["env"][key] for key in _SOURCE_ENV_KEYS}
    env["layout_file"] = None  # the layout text below identifies the map, wherever the file lives
    env["layout"] = layout
    key = {"env": env, "agent": plain["agent"], "seed": plain["seed"],
           "pretrain_steps": plain["transfer"]["pretrain_steps"]}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def pretrained_source(config: TrainConfig, plain: dict[str, Any], layout: str, launch_dir: Path) -> Path:
    """Pretrain on TreasureHunt-v0 once per source config; later runs reuse the cached checkpoint."""
    from dqn_transfer.train import TRAINING_STATE, train

    # Relative to the launch dir, like transfer.source: the process cwd may be a run dir (chdir, SLURM).
    cache_root = launch_dir / Path(config.transfer.cache_dir or "outputs/pretrained").expanduser()
    run_dir = cache_root / source_hash(plain, layout)
    checkpoint = run_dir / "checkpoints" / "agent_0.safetensors"
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        lock = open(run_dir / ".lock", "w")
    except OSError as err:
        raise TransferError(f"cannot use the pretraining cache {run_dir}: {err.strerror} "
                            "(set transfer.cache_dir to a writable directory)") from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # parallel sweep jobs: the first pretrains, the others wait
        if _is_complete(checkpoint, config.transfer.pretrain_steps):
            log.info("transfer: reusing the pretrained source %s", checkpoint)
            return checkpoint
        pretrain = source_config(config)
        resume = (run_dir / "checkpoints" / TRAINING_STATE).exists()  # a pretraining that was killed
        log.info("transfer: pretraining a source agent on TreasureHunt-v0 for %d steps into %s%s",
                 pretrain.total_steps, run_dir, " (resuming)" if resume else "")
        train(dataclasses.replace(pretrain, resume=resume), run_dir, source_task=True, launch_dir=launch_dir)
    return checkpoint


def _is_complete(checkpoint: Path, steps: int) -> bool:
    if not checkpoint.exists():
        return False
    _, meta = load_agent_checkpoint(checkpoint)
    return meta.get("steps") == steps


def resolve_source(transfer: TransferConfig, launch_dir: Path) -> Path:
    """A checkpoint file, or agent ``source_agent`` of a run/checkpoints directory."""
    path = Path(transfer.source).expanduser()
    if not path.is_absolute():
        path = launch_dir / path
    files = find_checkpoints(path)
    if path.is_file():
        return files[0]
    wanted = f"agent_{transfer.source_agent}.safetensors"
    for file in files:
        if file.name == wanted:
            return file
    raise CheckpointError(f"{path}: has no {wanted} (transfer.source_agent={transfer.source_agent}; "
                          f"found {', '.join(f.name for f in files)})")


def apply_transfer(config: TrainConfig, learner, game, plain: dict[str, Any], launch_dir: Path) -> dict[str, Any]:
    """Load the source into the target agents; returns what the run records about its source."""
    transfer = config.transfer
    targets = list(range(game.num_agents)) if transfer.targets is None else list(transfer.targets)
    bad = [i for i in targets if not 0 <= i < game.num_agents]
    if bad:
        raise TransferError(f"transfer.targets {bad} out of range for {game.num_agents} agents")
    pretrained = transfer.source is None
    path = pretrained_source(config, plain, game.map.layout, launch_dir) if pretrained else resolve_source(transfer, launch_dir)
    tensors, meta = load_agent_checkpoint(path)
    algorithm = plain["agent"]["algorithm"]
    target_layout = game.obs_layout()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            check_compatible(meta, {"algorithm": algorithm, "num_actions": game.num_actions, "size": game.size})
            if Algorithm(algorithm) in TABULAR:
                mapped = transfer_tabular_tensors(tensors, meta["obs_layout"], target_layout,
                                                  num_actions=game.num_actions)
            else:
                mapped = transfer_dqn_tensors(tensors, meta["obs_layout"], target_layout,
                                              list(config.agent.hidden), game.num_actions)
        except (CheckpointError, ValueError) as err:  # TransferError is a ValueError
            raise TransferError(f"transfer source {path}: {err}") from None
        except (KeyError, IndexError, TypeError) as err:  # a meta or tensor this format never writes
            raise TransferError(f"transfer source {path}: malformed checkpoint ({type(err).__name__}: {err})") from None
    for warning in caught:
        log.warning("transfer: %s", warning.message)
    for i in targets:
        learner.load_agent_tensors(i, mapped)
    if not transfer.reset_optimizer:
        if len(targets) != game.num_agents:  # Adam keeps one step count per stacked parameter
            raise TransferError("transfer.reset_optimizer=false needs every agent as a target "
                                f"(transfer.targets={targets}): the agents share Adam's step count")
        carry_optimizer_state(learner, path, meta, target_layout, targets)
    if transfer.freeze:  # indices were checked against agent.hidden by config.validate
        learner.freeze(transfer.freeze)
    info = {
        "source": str(path.resolve()),
        "digest": meta["digest"],
        "source_algorithm": meta.get("algorithm"),
        "source_obs_layout": meta["obs_layout"],
        "source_steps": meta.get("steps"),
        "pretrained": pretrained,
        "targets": targets,
    }
    log.info("transfer: agents %s start from %s (digest %s...)", targets, path, meta["digest"][:12])
    return info


def carry_optimizer_state(learner, source: Path, meta: dict[str, Any], target_layout, targets: list[int]) -> None:
    """``transfer.reset_optimizer=false``: start the targets' Adam moments from the source's.

    The moments live in the source run's resume state beside the agent file; the first layer's rows
    are mapped by segment like its weights (zero for target-only segments).
    """
    from dqn_transfer.train import TRAINING_STATE

    if not hasattr(learner, "set_member_optimizer_state"):
        raise TransferError("transfer.reset_optimizer=false needs a DQN learner (tabular learners have no optimizer)")
    state_path = source.parent / TRAINING_STATE
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


# ------------------------------------------------------------------------------ team knowledge exchange

def exchange_best(learner, window_returns: np.ndarray, tau: float) -> int:
    """Every other agent moves its weights ``tau`` of the way to the best agent's (soft copy).

    Layers kept fixed by ``transfer.freeze`` stay as they are. The best agent is the one with the highest mean episodic return over the exchange window.
    """
    best = int(np.argmax(window_returns.mean(axis=0)))
    best_weights = learner.get_member_weights(best)
    frozen = {f"layers.{l}.{kind}" for l in learner.frozen_layers for kind in ("weight", "bias")}
    for i in range(learner.num_agents):
        if i != best:
            own = learner.get_member_weights(i)
            learner.set_member_weights(i, {name: own[name] if name in frozen else
                                           (1 - tau) * own[name] + tau * best_weights[name] for name in own})
    return best


def exchange_replay(learner, transitions: Sequence[tuple]) -> None:
    """Each agent adds its team-mates' transitions of the window to its own replay row."""
    if not transitions:
        return
    obs, actions, rewards, next_obs, terminated, truncated, live = (np.stack(column) for column in zip(*transitions))
    for giver in range(learner.num_agents):
        taken = live[:, giver]  # only the steps where the giver was acting
        experience = [field[taken, giver] for field in (obs, actions, rewards, next_obs, terminated, truncated)]
        for receiver in range(learner.num_agents):
            if receiver != giver:
                learner.replay.extend(receiver, *experience)
