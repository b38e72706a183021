"""``dqn-transfer-ckpt export RUN_DIR OUT_DIR``: a trained team as one folder to hand to a colleague or
upload to a model hub as it is.

::

    OUT_DIR/
      README.md              the model card: YAML front matter (library_name, tags, the env and mode
                             config, the evaluation metrics with their seeds) and how to warm-start
      agent_{i}.safetensors  the agents' checkpoints, byte for byte (each verified first; a lone agent
                             file given instead of a run is agent_0 here, so it is the default source)
      map.txt                the map as it was played (an ASCII layout)
      replay.gif             the team's first evaluation episode

``transfer.source=OUT_DIR`` warm-starts a new run from the folder. The card's metrics are measured
when exporting, on greedy episodes whose seeds it states, so ``dqn-transfer-play OUT_DIR --episodes N
--seed S`` reproduces them. The folder appears whole or not at all: everything is written into a
temporary sibling, which is renamed to OUT_DIR once complete (and removed on any failure, with the
missing parent directories the export made for it).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dqn_transfer.documented import format_default
from dqn_transfer.enums import Algorithm
from dqn_transfer.envs import PettingZooGame, TreasureHuntGame
from dqn_transfer.envs.settings import DEFAULTS, MAP_KEYS, EnvConfig
from dqn_transfer.evaluation.rollout import summarize
from dqn_transfer.evaluation.watch import RecordedEpisode, gif_bytes, watch_team
from dqn_transfer.sharing.team import TeamError, TrainedTeam, load_team
from dqn_transfer.storage.checkpoint import CheckpointError, atomic_write_all
from dqn_transfer.storage.run_dir import file_in_the_way

CARD_FILE, MAP_FILE, GIF_FILE = "README.md", "map.txt", "replay.gif"
EVAL_EPISODES, EVAL_SEED = 10, 0
LIBRARY_NAME = "dqn-transfer"
ENV_ID = "treasure_hunt_v0"
# Env keys the card's warm-start command leaves out: the map is map.txt, the mode has its own group,
# and rendering changes nothing learned.
NOT_IN_COMMAND = (*MAP_KEYS, "mode", "render_mode")


class ExportError(Exception):
    """The team cannot be exported there; the message is one user-facing line."""


def export_team(run_path: str | Path, out_dir: str | Path) -> Path:
    """Write the folder (see the module docstring) for the team at ``run_path``; returns ``out_dir``."""
    out_dir = Path(out_dir)
    check_destination(out_dir)
    try:
        team = load_team(run_path)
    except TeamError as err:
        raise ExportError(str(err)) from None
    game = team.game
    if isinstance(game, PettingZooGame):
        raise ExportError(f"{run_path}: a team of {game.factory}: an export (map, model card) is a treasure hunt's")
    episodes = watch_team(game, team.learner, EVAL_EPISODES, EVAL_SEED)
    files = {out_dir / f"agent_{i}.safetensors": file.read_bytes() for i, file in enumerate(unique(team.files))}
    files[out_dir / MAP_FILE] = (game.map.layout + "\n").encode()
    files[out_dir / GIF_FILE] = gif_bytes(episodes[:1])
    files[out_dir / CARD_FILE] = model_card(team, game, episodes).encode()
    write_folder(out_dir, files)
    return out_dir


def unique(files: list[Path]) -> list[Path]:
    """A lone agent file drives every agent of its map, but is exported once."""
    return list(dict.fromkeys(files))


def check_destination(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir} is a file; give a new folder to export into")
    if out_dir.is_dir() and any(out_dir.iterdir()):
        raise ExportError(f"{out_dir} is not empty; give a new or empty folder to export into")
    if (file := file_in_the_way(out_dir.parent)) is not None:
        raise ExportError(f"cannot export into {out_dir}: {file} is a file")


def write_folder(out_dir: Path, files: dict[Path, bytes]) -> None:
    """All of ``files`` (paths inside ``out_dir``) into ``out_dir`` at once, or nothing; the parent
    directories ``out_dir`` lacks are made (``shared/team`` in a fresh folder), and removed on a failure."""
    temp = out_dir.with_name(f".{out_dir.name}.export-{secrets.token_hex(4)}")
    made = [parent for parent in out_dir.absolute().parents if not parent.exists()]  # nearest first
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        temp.mkdir()
        atomic_write_all({temp / path.relative_to(out_dir): data for path, data in files.items()})
        os.rename(temp, out_dir)  # replaces an empty out_dir; refused if someone filled it meanwhile
    except (OSError, CheckpointError) as err:
        shutil.rmtree(temp, ignore_errors=True)
        for parent in made:
            with contextlib.suppress(OSError):  # only if still empty: never what another process put there
                parent.rmdir()
        reason = err.strerror if isinstance(err, OSError) else str(err)
        raise ExportError(f"cannot export into {out_dir}: {reason}") from None


# ------------------------------------------------------------------------------------ the card


def evaluation(episodes: list[RecordedEpisode]) -> dict[str, Any]:
    """The card's metrics: means over the greedy episodes, with the seeds that reproduce them."""
    results = [episode.result for episode in episodes]
    record = summarize(results)
    return {
        "episodes": len(results),
        "seed": EVAL_SEED,
        "episode_seeds": [[EVAL_SEED, i] for i in range(len(results))],
        "team_return_mean": round(record["team_return"], 3),
        "team_return_std": round(float(np.std([r.team_return for r in results])), 3),
        **{key: round(record[key], 3) for key in ("success_rate", "trap_rate", "episode_length")},
        "reproduce": f"dqn-transfer-play $FOLDER --episodes {len(results)} --seed {EVAL_SEED}",
    }


def algorithm_tags(algorithm: Algorithm) -> list[str]:
    if algorithm.is_tabular:
        return ["tabular", algorithm.value.replace("_", "-")]
    return sorted({"dqn", algorithm.value.replace("_", "-")})


def warm_start_command(team: TrainedTeam) -> str:
    """``python train.py ...`` that warm-starts a run of the same game and network from the folder
    ``$FOLDER``: the map, the mode, the learner, its network and every rule that differs from the default."""
    meta, env = team.meta, team.meta["env"]
    overrides = [
        f"agent={meta['algorithm']}",
        f"mode={meta['mode']}",
        "transfer=on",
        "transfer.source=$FOLDER",
        f"env.layout_file=$FOLDER/{MAP_FILE}",
    ]
    # The schema's defaults as the checkpoint's JSON meta spells them (enums by their value).
    defaults = {f.name: getattr(DEFAULTS, f.name) for f in fields(EnvConfig) if f.name not in NOT_IN_COMMAND}
    defaults = {key: getattr(value, "value", value) for key, value in defaults.items()}
    overrides += [
        f"env.{key}={format_default(env[key])}" for key, default in defaults.items() if env.get(key, default) != default
    ]  # a key newer than the checkpoint has its default
    if "hidden" in meta["network"]:
        overrides.append(f"'agent.hidden={format_default(meta['network']['hidden'])}'")
    return "python train.py " + " ".join(overrides)


def warm_starts(meta: dict[str, Any]) -> list[dict[str, Any]]:
    """Where the team's agents started from, oldest first: each warm start of the chain behind agent 0's
    checkpoint (a curriculum's stages, a pretrained source), or none for a team trained from scratch."""
    chain, record = [], meta.get("transfer")
    while record:
        mapping = record.get("mapping") or {}
        size = mapping.get("source_size")
        chain.append(
            {
                "source": record.get("source"),
                "source_steps": record.get("source_steps"),
                "pretrained_source": bool(record.get("pretrained")),
                "source_map": f"{size}x{size}" if size else None,
                "offset": mapping.get("offset"),
                "digest": record.get("digest"),
            }
        )
        record = record.get("source_transfer")
    return chain[::-1]


def started_from(chain: list[dict[str, Any]]) -> str:
    """The card's paragraph on where the agents started."""
    if not chain:
        return "From scratch: random weights (or an all-zero Q-table); no warm start."
    rows = [
        f"{n}. `{step['source']}` ({step['source_steps']} steps"
        + (", pretrained on TreasureHunt-v0" if step["pretrained_source"] else "")
        + (f", a {step['source_map']} map placed at {step['offset']}" if step["source_map"] else "")
        + ")"
        for n, step in enumerate(chain, start=1)
    ]
    what = "a curriculum of warm starts" if len(chain) > 1 else "a warm start"
    return (
        f"Warm-started, through {what} (oldest first; agent 0's checkpoint records the chain, "
        "`warm_started_from` above):\n\n" + "\n".join(rows)
    )


def model_card(team: TrainedTeam, game: TreasureHuntGame, episodes: list[RecordedEpisode]) -> str:
    meta = team.meta
    algorithm = Algorithm(meta["algorithm"])
    metrics = evaluation(episodes)
    size = f"{game.size}x{game.size}"
    name = f"{algorithm.value}-{ENV_ID}-{meta['mode']}-{size}"
    front = {
        "library_name": LIBRARY_NAME,
        "license": "mit",
        "tags": ["reinforcement-learning", "multi-agent", *algorithm_tags(algorithm), "treasure-hunt", "pettingzoo"],
        "model-index": [
            {
                "name": name,
                "results": [
                    {
                        "task": {"type": "reinforcement-learning", "name": "reinforcement-learning"},
                        "dataset": {
                            "name": f"{ENV_ID} ({meta['mode']}, {size}, {game.num_agents} agents)",
                            "type": ENV_ID,
                        },
                        "metrics": [
                            {
                                "type": "mean_reward",
                                "name": "mean team return",
                                "value": f"{metrics['team_return_mean']:.2f} +/- {metrics['team_return_std']:.2f}",
                                "verified": False,
                            }
                        ],
                    }
                ],
            }
        ],
        "env": {key: value for key, value in meta["env"].items() if key != "layout"},
        "mode": meta["mode"],
        "algorithm": algorithm.value,
        "agents": game.num_agents,
        "network": meta["network"],
        "training": {
            "seed": meta["seed"],
            "steps": meta["steps"],
            "episodes": meta["episodes"],
            "last_evaluation": meta.get("last_eval") or None,
        },
        "warm_started_from": warm_starts(meta) or None,
        "evaluation": metrics,
    }
    agent_files = ", ".join(f"`agent_{i}.safetensors`" for i in range(len(unique(team.files))))
    return f"""---
{yaml.safe_dump(front, sort_keys=False, width=120, default_flow_style=None).rstrip()}
---

# {name}

A team of {game.num_agents} {algorithm.value} agents trained with dqn_transfer on the treasure hunt
({meta["mode"]} mode, a {size} map with {game.num_treasures} chests and {game.map.num_traps} traps) for
{meta["steps"]} steps (seed {meta["seed"]}). Each agent observes the expanded state
{", ".join(f"`{name}` ({size_})" for name, size_ in meta["obs_layout"])} and acts greedily on its Q-values.

![the team's first evaluation episode]({GIF_FILE})

## Where its agents started

{started_from(warm_starts(meta))}

## The map

```
{game.map.layout}
```

`.` free, `#` obstacle, `T` chest, `X` trap, digits: the agents' starts (also in `{MAP_FILE}`).

## Evaluation

{metrics["episodes"]} greedy episodes, episode i drawing its chest ties from the seed ({EVAL_SEED}, i);
`{metrics["reproduce"]}` plays them again (`$FOLDER`: where this folder is).

| mean team return | std | success rate (chests taken) | trap rate | episode length |
|---:|---:|---:|---:|---:|
| {metrics["team_return_mean"]:g} | {metrics["team_return_std"]:g} | {metrics["success_rate"]:g} | {metrics["trap_rate"]:g} | {metrics["episode_length"]:g} |

## Warm-start from it

With dqn_transfer installed, a new run of the same game starts each agent from the agent of its own
index in this folder (at step 0 they compute exactly their Q-values):

```bash
FOLDER=path/to/this/folder
{warm_start_command(team)}
```

`transfer.source_agent=1` starts every agent from agent 1 instead (a list gives each new agent its own);
a team of another size starts every agent from agent 0 unless a list says otherwise;
`transfer.targets=[0]` warm-starts agent 0 only. Another mode works too, and so
does a larger map holding this one at `transfer.offset=[row, col]`: inputs only the new run has start
at zero weight. Watch the team: `dqn-transfer-play $FOLDER`; check the files: `dqn-transfer-ckpt verify $FOLDER`.

## Files

- {agent_files}: each agent's tensors (safetensors, never a pickle) and a JSON `meta` (algorithm,
  observation layout, network, env, training steps, a SHA-256 digest of the tensors)
- `{MAP_FILE}`: the map; `{GIF_FILE}`: the team's first evaluation episode, one frame per step
"""  # noqa: E501 (a Markdown table row)
