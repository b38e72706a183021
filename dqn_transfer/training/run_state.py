"""A replica's checkpoint, both ways: what its files hold, and how a resumed run reads it back.

A checkpoint writes, per replica, one ``agent_{i}.safetensors`` per agent (for sharing: tensors and
a meta that says what the agent is and the map it was trained on) and ``training_state.safetensors``
(what alone is read on resume: the learner's whole state, the counters, the exchange window and the
episode in progress, so a resumed run replays exactly what the uninterrupted run would have).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from dqn_transfer.enums import Algorithm
from dqn_transfer.storage.checkpoint import (
    CheckpointError,
    atomic_write,
    encode_agent_checkpoint,
    encode_training_state,
    load_training_state,
)
from dqn_transfer.training.replica import Counters, Replica

log = logging.getLogger("dqn_transfer.train")


def agent_meta(rep: Replica, index: int, algorithm: Algorithm, source_task: bool) -> dict[str, Any]:
    """What ``agent_{index}.safetensors`` says about itself."""
    game, plain = rep.game, rep.plain_config
    return {
        "algorithm": algorithm.value,
        "agent_index": index,
        "obs_layout": [[name, size] for name, size in rep.learner.obs_layout],  # the networks' inputs
        "num_actions": game.num_actions,
        "network": rep.learner.network_meta(),
        # The game as played: for the treasure hunt its map (``make_game(**meta["env"])`` rebuilds it from
        # the layout alone), for another game its factory, kwargs and spaces.
        "env": {**plain["env"], **game.recorded_env()},
        "mode": plain["env"]["mode"],
        "source_task": source_task,
        "agent": plain["agent"],
        "seed": rep.config.seed,
        "steps": rep.counters.step,
        "episodes": rep.counters.episodes,
        "last_eval": rep.last_eval,
        "transfer": rep.transfer_info,
    }


def encode_checkpoint(
    rep: Replica, algorithm: Algorithm, source_task: bool, game_state: dict[str, Any] | None
) -> tuple[dict[Path, bytes], Path, bytes]:
    """The replica's agent files by path, and the path and bytes of its resume state; ``game_state``:
    its episode in progress (None before the loop starts)."""
    rep.counters.env_rng_state = dict(rep.env_rng.bit_generator.state)
    files: dict[Path, bytes] = {}
    arrays: dict[str, np.ndarray] = {}
    for i in range(rep.game.num_agents):
        tensors = dict(rep.learner.agent_tensors(i))
        files[rep.run_dir.agent_checkpoint(i)] = encode_agent_checkpoint(
            tensors, agent_meta(rep, i, algorithm, source_task)
        )
        arrays.update({f"agent_{i}/{name}": t for name, t in tensors.items()})
    learner_arrays, learner_meta = rep.learner.training_state()
    arrays.update({f"learner/{name}": a for name, a in learner_arrays.items()})
    arrays["exchange/returns"] = np.asarray(rep.window_returns, dtype=np.float64).reshape(-1, rep.game.num_agents)
    arrays.update({f"exchange/{name}": a for name, a in rep.exchange.state(rep.index).items()})
    meta = {
        "counters": rep.counters.__dict__,
        "learner": learner_meta,
        "last_eval": rep.last_eval,
        "transfer": rep.transfer_info,
        "obs_layout": [[name, size] for name, size in rep.learner.obs_layout],
        "algorithm": algorithm.value,
        "config": rep.plain_config,  # what resume=true continues with
        "layout": rep.game.identity(),  # the map itself (a layout file may have changed since), or the game's spaces
        # The episode in progress (None before the loop starts).
        "episode": None if game_state is None else {"game": game_state, "stats": rep.episode.state_dict()},
    }
    return files, rep.run_dir.training_state, encode_training_state(arrays, meta)


def load_checkpoint(rep: Replica, algorithm: Algorithm) -> None:
    """Restore the replica from its resume state, refusing one made with another learner or map."""
    arrays, meta = load_training_state(rep.run_dir.training_state)
    expected_layout = [[name, size] for name, size in rep.learner.obs_layout]
    if meta.get("obs_layout") != expected_layout or meta.get("algorithm") != algorithm.value:
        raise CheckpointError(
            f"{rep.run_dir.checkpoints}: the run was made with algorithm {meta.get('algorithm')} and obs layout "
            f"{meta.get('obs_layout')}; this config gives {algorithm.value} and {expected_layout}"
        )
    if meta.get("layout") != rep.game.identity():
        raise CheckpointError(
            f"{rep.run_dir.checkpoints}: the run was trained on another map:\n"
            f"{meta.get('layout')}\nthis config gives\n{rep.game.identity()}"
        )
    try:  # tensors the learner cannot take (a shape, a table key that is no observation of this game)
        for i in range(rep.game.num_agents):
            prefix = f"agent_{i}/"
            agent = {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)}
            rep.learner.load_agent_tensors(i, agent)
        rep.learner.load_training_state(
            {k[len("learner/") :]: v for k, v in arrays.items() if k.startswith("learner/")}, meta["learner"]
        )
    except ValueError as err:
        raise CheckpointError(f"{rep.run_dir.training_state}: {err}") from None
    rep.counters = Counters(**meta["counters"])
    rep.window_returns = list(arrays.get("exchange/returns", []))
    window = {k[len("exchange/") :]: v for k, v in arrays.items() if k.startswith("exchange/")}
    rep.exchange.load_state(rep.index, window, rep.game.num_agents)
    rep.last_eval = meta["last_eval"]
    rep.transfer_info = meta["transfer"]
    rep.episode_state = meta.get("episode")  # None at an episode end (and in older checkpoints)
    _truncate_metrics(rep, rep.counters.evaluations)
    log.info("resumed %s at step %d (episode %d)", rep.run_dir, rep.counters.step, rep.counters.episodes)


def _truncate_metrics(rep: Replica, evaluations: int) -> None:
    """Keep the evaluations the checkpoint counted; the killed run's later ones will be redone.

    By count, not by step: a line at the checkpoint's step may be one the checkpoint does not
    know about (written after it, by a run killed before its next checkpoint).
    """
    if not rep.run_dir.metrics.exists():
        return
    lines = [line for line in rep.run_dir.metrics.read_text().splitlines() if line.strip()][:evaluations]
    atomic_write(rep.run_dir.metrics, "".join(line + "\n" for line in lines).encode())
    rep.last_eval_step = json.loads(lines[-1])["step"] if lines else None
