"""The transfer hook: load a source agent's checkpoint into the target agents of a fresh run.

The source is a path per target agent (:mod:`dqn_transfer.sources.resolve` finds or pretrains it); the
mapping onto the target's observation and map is by segment name and by aligned cell
(:mod:`dqn_transfer.transfer.mapping`): segments, cells and chests only the target has get zero
input weights, so at step 0 the transferred agents compute the source's Q-values on every state of
the source's map.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from dqn_transfer.agents import Team, WarmStart
from dqn_transfer.config import TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Fill
from dqn_transfer.envs import Game, PettingZooGame, TreasureHuntGame
from dqn_transfer.envs.game import make_game
from dqn_transfer.envs.maps import Cell, GridMap
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.storage.checkpoint import (
    CheckpointError,
    check_compatible,
    load_agent_checkpoint,
    load_training_state,
)
from dqn_transfer.storage.run_dir import TRAINING_STATE_FILE
from dqn_transfer.transfer.mapping import (
    Embedding,
    Layout,
    MapGeometry,
    SegmentPlan,
    TransferError,
    map_input_moments,
    plan_segment_mapping,
    segment_slices,
    transfer_agent_tensors,
)

log = logging.getLogger("dqn_transfer.transfer")


def transfer_targets(config: TrainConfig, num_agents: int) -> list[int]:
    """The agents that receive the transfer (``transfer.targets``, default all), checked when the run is
    planned."""
    targets = list(range(num_agents)) if config.transfer.targets is None else list(config.transfer.targets)
    bad = [i for i in targets if not 0 <= i < num_agents]
    if bad:
        raise TransferError(f"transfer.targets {bad} out of range for {num_agents} agents")
    if not config.transfer.reset_optimizer and len(targets) != num_agents:  # one Adam step count per stacked parameter
        raise TransferError(
            f"transfer.reset_optimizer=false needs every agent as a target (transfer.targets={targets}): "
            "the agents share Adam's step count"
        )
    return targets


def map_geometry(game: TreasureHuntGame) -> MapGeometry:
    """What the transfer mapping reads of a game's map."""
    return MapGeometry(game.size, game.map.chests, game.obs_encoding.value, game.position_codes())


def check_same_game(meta: Mapping[str, Any], game: Game) -> None:
    """Refuse a source trained on another game: the treasure hunt and a PettingZoo env, or two factories.

    :param meta: the source checkpoint's meta (its ``env`` records ``factory``; older ones none).
    :param game: this run's game.
    """
    env = meta.get("env")
    source = env.get("factory") if isinstance(env, Mapping) else None
    target = game.factory if isinstance(game, PettingZooGame) else None
    if source != target:
        raise TransferError(
            f"the source was trained on {source or 'the treasure hunt'} and this run plays "
            f"{target or 'the treasure hunt'}: a warm start needs the same game"
        )


def recorded_game(meta: Mapping[str, Any]) -> TreasureHuntGame | None:
    """The treasure hunt a source recorded in its meta (its map rebuilt from the layout alone); None for
    a source that recorded no map."""
    env = meta.get("env")
    if not isinstance(env, Mapping) or env.get("layout") is None:
        return None
    try:
        return make_game(**{key: value for key, value in env.items() if key in ENV_KEYS})
    except ValueError as err:
        raise TransferError(f"the source's recorded map is invalid: {err}") from None


def source_embedding(
    source_game: TreasureHuntGame | None, meta: Mapping[str, Any], game: Game, transfer: TransferConfig
) -> Embedding | None:
    """Where the source's map (``source_game``'s, :func:`recorded_game`) sits in ``game``'s
    (``transfer.offset``, ``transfer.fill``); None for a source that recorded none (then its map must be
    this one) and for a game without a map (a PettingZoo env: its segments are mapped by name alone)."""
    if isinstance(game, PettingZooGame):
        if list(transfer.offset) != [0, 0] or Fill(transfer.fill) is not Fill.zero:
            raise TransferError(f"transfer.offset and transfer.fill place a treasure-hunt map; {game.factory} has none")
        return None
    if source_game is None:
        if list(transfer.offset) != [0, 0] or Fill(transfer.fill) is not Fill.zero:
            raise TransferError("the source does not record its map, which transfer.offset and transfer.fill need")
        check_compatible(meta, {"size": game.size})
        return None
    return Embedding(
        map_geometry(source_game),
        map_geometry(game),
        (int(transfer.offset[0]), int(transfer.offset[1])),
        Fill(transfer.fill).value,
    )


def source_chest_column(start: Cell, source_map: GridMap, embedding: Embedding, target_layout: Layout) -> int:
    """``transfer.chest_aware``: the target observation column that says whether the source's chest is
    full. The source's chest is the one nearest its ``start`` (:meth:`GridMap.nearest_chest`), the chest
    a lone agent from there is trained to reach; its column is the `treasures` entry of the target chest
    on its cell (refused if the target has none there)."""
    chest = source_map.nearest_chest(start)
    target_chest = int(embedding.chest_targets()[chest])
    if target_chest < 0:
        r, c = source_map.chests[chest]
        raise TransferError(
            f"transfer.chest_aware=true: the source's chest (row {r}, col {c}, the nearest to its start) has no "
            f"chest on its cell in this run's map (transfer.offset={list(embedding.offset)})"
        )
    return segment_slices(target_layout)["treasures"].start + target_chest


@dataclass
class MappedSource:
    """One source checkpoint mapped onto this run's agents; ``start``: where the source agent started on
    its recorded map (None for a source that recorded none)."""

    path: Path
    tensors: dict[str, np.ndarray]
    meta: dict[str, Any]
    plan: SegmentPlan
    embedding: Embedding | None
    start: Cell | None

    def record(self) -> dict[str, Any]:
        """What the run records about this source: the file, and the mapping onto this run's map."""
        record = {
            "source": str(self.path.resolve()),
            "digest": self.meta["digest"],
            "source_agent": self.meta.get("agent_index"),
            "source_algorithm": self.meta.get("algorithm"),
            "source_obs_layout": self.meta["obs_layout"],
            "source_steps": self.meta.get("steps"),
        }
        if self.embedding is not None:
            record["mapping"] = {
                "source_size": self.embedding.source.size,
                "offset": list(self.embedding.offset),
                "fill": self.embedding.fill,
                "dropped_chests": [list(cell) for cell in self.embedding.dropped_chests()],
            }
        # The source's own origin, so a chain of warm starts (a curriculum) is recorded whole.
        record["source_transfer"] = self.meta.get("transfer")
        return record


def map_source(config: TrainConfig, game: Game, path: Path, target_layout: Layout) -> MappedSource:
    """Load ``path`` and map its tensors onto ``game``'s agents, whose inputs are ``target_layout`` (the
    learner's: the game's segments, and ``agent_id`` with ``agent.agent_id_input``); every refusal is one
    TransferError line."""
    tensors, meta = load_agent_checkpoint(path)
    algorithm = Algorithm(config.agent.algorithm)
    try:
        check_compatible(meta, {"algorithm": algorithm.value, "num_actions": game.num_actions})
        check_same_game(meta, game)
        source_game = None if isinstance(game, PettingZooGame) else recorded_game(meta)
        embedding = source_embedding(source_game, meta, game, config.transfer)
        start = source_game.map.starts[int(meta.get("agent_index") or 0)] if source_game is not None else None
        plan = plan_segment_mapping(meta["obs_layout"], target_layout, embedding)
        gate = None
        if config.transfer.chest_aware:
            if start is None or source_game is None or embedding is None:
                raise TransferError("transfer.chest_aware=true needs a source that records its map")
            gate = source_chest_column(start, source_game.map, embedding, target_layout)
        mapped = transfer_agent_tensors(
            tensors,
            meta["obs_layout"],
            target_layout,
            list(config.agent.hidden),
            game.num_actions,
            embedding,
            gate_column=gate,
        )
    except (CheckpointError, ValueError) as err:  # TransferError is a ValueError
        raise TransferError(f"transfer source {path}: {err}") from None
    except (KeyError, IndexError, TypeError) as err:  # a meta or tensor this format never writes
        raise TransferError(f"transfer source {path}: malformed checkpoint ({type(err).__name__}: {err})") from None
    return MappedSource(path, mapped, meta, plan, embedding, start)


def apply_transfer(
    config: TrainConfig, learner: Team, game: Game, source: Path | Sequence[Path], targets: list[int]
) -> dict[str, Any]:
    """Load ``source`` (one checkpoint for every target agent, or one per target) into the ``targets``
    (the plan's :func:`transfer_targets`) with ``load_agent_tensors``; keeping layers fixed and carrying
    the optimizer state over need the learner's :class:`~dqn_transfer.agents.WarmStart` capability (the
    DQN family: the schema refuses either with a table, the plan a partial carry-over).
    Returns what the run records about its sources."""
    transfer = config.transfer
    files = [source] * len(targets) if isinstance(source, Path) else list(source)
    if len(files) != len(targets):
        raise TransferError(f"{len(files)} source checkpoints for {len(targets)} target agents {targets}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mapped = {path: map_source(config, game, path, learner.obs_layout) for path in dict.fromkeys(files)}
    for warning in caught:
        log.warning("transfer: %s", warning.message)
    per_target = [mapped[path] for path in files]
    for i, source_i in zip(targets, per_target):
        learner.load_agent_tensors(i, source_i.tensors)
    if not transfer.reset_optimizer:
        carry_optimizer_state(cast(WarmStart, learner), per_target, targets)
    if transfer.freeze:  # indices were checked against agent.hidden by config.validate
        cast(WarmStart, learner).freeze(list(transfer.freeze))
    first = per_target[0]
    log.info(
        "transfer: agents %s start from %s (digest %s...)",
        targets,
        first.path if len(mapped) == 1 else ", ".join(str(path) for path in files),
        first.meta["digest"][:12],
    )
    return {
        **first.record(),
        "pretrained": bool(first.meta.get("source_task")),  # trained on the single-agent source task
        "targets": targets,
        # With another source agent per target (another team size, per-agent sources): which file each
        # target took, and where its source agent started.
        "per_target": None
        if len(mapped) == 1
        else [
            {
                "source": str(s.path.resolve()),
                "digest": s.meta["digest"],
                "source_agent": s.meta.get("agent_index"),
                "source_start": None if s.start is None else list(s.start),
            }
            for s in per_target
        ],
    }


def lineage(record: Mapping[str, Any] | None) -> list[Mapping[str, Any]]:
    """The chain of warm starts behind a run's transfer record, oldest first (a curriculum's stages)."""
    chain = []
    while record:
        chain.append(record)
        record = record.get("source_transfer")
    return chain[::-1]


def lineage_table(record: Mapping[str, Any]) -> str:
    """The chain of warm starts as a Markdown table (TensorBoard's text tab renders it)."""
    rows = ["| warm start | from checkpoint | its map | its steps | placed at | digest |", "|---|---|---|---|---|---|"]
    for n, step in enumerate(lineage(record), start=1):
        mapping = step.get("mapping") or {}
        size = mapping.get("source_size")
        rows.append(
            f"| {n} | {step['source']} | {f'{size}x{size}' if size else '-'} | {step.get('source_steps')} "
            f"| {mapping.get('offset', '-')} | {step['digest'][:12]} |"
        )
    return "\n".join(rows)


def carry_optimizer_state(learner: WarmStart, sources: list[MappedSource], targets: list[int]) -> None:
    """``transfer.reset_optimizer=false``: start each target's Adam moments from its source's.

    The moments live in the source run's resume state beside the agent file; the first layer's rows
    are mapped like its weights (:func:`~dqn_transfer.transfer.mapping.map_input_moments`).
    """
    states = {source.path: _source_moments(source) for source in sources}
    steps = sorted({step for _, step in states.values()})
    if len(steps) > 1:  # Adam keeps one step count per stacked parameter
        raise TransferError(
            f"transfer.reset_optimizer=false: the sources' optimizers are at different steps "
            f"{steps}; use reset_optimizer=true"
        )
    for i, source in zip(targets, sources):
        learner.load_optimizer_state(i, states[source.path][0], steps[0])


def _source_moments(source: MappedSource) -> tuple[dict[str, dict[str, np.ndarray]], int]:
    """The Adam moments of ``source``'s agent from its run's resume state, mapped onto this run, and their step."""
    meta, state_path = source.meta, source.path.parent / TRAINING_STATE_FILE
    if not state_path.exists():
        raise TransferError(
            f"transfer.reset_optimizer=false needs the source's optimizer state, but {state_path} "
            "does not exist (share the run's whole checkpoints/ directory, or use reset_optimizer=true)"
        )
    arrays, state_meta = load_training_state(state_path)
    if (
        state_meta.get("counters", {}).get("step") != meta.get("steps")
        or state_meta.get("obs_layout") != meta["obs_layout"]
    ):
        raise TransferError(
            f"{state_path} is not the resume state of {source.path.name} (other steps or obs layout); "
            "use reset_optimizer=true"
        )
    member = 0 if meta["network"].get("share_parameters") else int(meta["agent_index"])
    moments: dict[str, dict[str, np.ndarray]] = {}
    step = 0
    for layer in range(len(meta["network"]["hidden"]) + 1):
        for name in (f"weight_{layer}", f"bias_{layer}"):
            prefix = f"learner/optim.{name}."
            if prefix + "exp_avg" not in arrays:  # frozen in the source, or it never trained
                continue
            step = int(np.asarray(arrays[prefix + "step"]).reshape(-1)[0])
            exp_avg, exp_avg_sq = arrays[prefix + "exp_avg"][member], arrays[prefix + "exp_avg_sq"][member]
            if name == "weight_0":  # [in, out]: rows are observation columns
                exp_avg, exp_avg_sq = map_input_moments(source.plan, source.embedding, exp_avg, exp_avg_sq)
            moments[name] = {"exp_avg": exp_avg, "exp_avg_sq": exp_avg_sq}
    return moments, step
