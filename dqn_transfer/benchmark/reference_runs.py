"""Fixed-seed reference runs: record them before a refactor, again after, and show 0 files different
(``python scripts/reference_runs.py OUT`` records, ``--compare A B`` compares two recordings).

Every run goes through the command line (``python -m dqn_transfer.cli.train``, ``-ckpt``, ``-play``)
inside one fixed working directory (:data:`WORK_DIR`, then moved to ``OUT``), so every path written into a
file (configs, checkpoint headers, cache keys) is the same in two recordings. A digest is the SHA-256
of a file's bytes, except for the few things that hold a clock or a process:
``metrics.jsonl`` lines lose ``wall_time``; TensorBoard events, logs and Hydra's own record are left out.
Each run is small (about a thousand steps); the whole set takes a few minutes on 2 cores.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

TRAIN = [sys.executable, "-m", "dqn_transfer.cli.train"]
SMALL = ["total_steps=1200", "eval_every=400", "eval_episodes=3", "checkpoint_every=600", "progress=false"]
# name: its overrides, as on a command line. Together they touch every learner, engine, mode, encoding,
# transfer path, exchange kind, replicas, a curriculum and a resume.
RUNS: dict[str, list[str]] = {
    name: overrides.split()
    for name, overrides in {
        "default": "",
        "dqn_numpy_cooperative": "agent=dqn agent.engine=numpy mode=cooperative",
        "double_dqn_numpy_deliberative": "agent.engine=numpy mode=deliberative env=complex",
        "dqn_torch_hard_target": "agent=dqn agent.target_update=100 agent.tau=1.0 agent.learning_starts=200",
        "sarsa_deliberative_complex": "agent=sarsa mode=deliberative env=complex total_steps=3000",
        "qlearning_cooperative_team_reward": "agent=qlearning mode=cooperative env.reward_mode=team",
        "sarsa_coords": "agent=sarsa env.obs_encoding=coords",
        "dqn_view_shared": "agent=dqn env.view_radius=1 agent.share_parameters=true agent.learning_starts=200",
        "transfer_pretrained": "transfer=on transfer.pretrain_steps=800",
        "transfer_team_numpy": "transfer=on transfer.source_task=team transfer.pretrain_steps=800 "
        "agent.engine=numpy mode=cooperative",
        "transfer_sarsa_shifted": "agent=sarsa transfer=on transfer.source_map_shift=1000 transfer.pretrain_steps=800",
        "transfer_from_run": "transfer=on transfer.source=runs/default transfer.targets=[1]",
        "replicas_sarsa": "agent=sarsa replicas.seeds=2 replicas.maps=2 mode=cooperative",
        "replicas_double_dqn_numpy": "agent.engine=numpy replicas.seeds=2 agent.learning_starts=200",
        "replicas_dqn_torch": "agent=dqn replicas.seeds=2 agent.learning_starts=200",
        # Enough replicas that every game steps in one batch, with chest ties and the coordinator.
        "replicas_sarsa_deliberative": "agent=sarsa replicas.seeds=6 mode=deliberative env=complex",
        "replicas_qlearning_view_competitive": "agent=qlearning replicas.seeds=5 mode=competitive "
        "env.view_radius=1 env.reward_mode=team",
        "exchange_best": "mode=cooperative transfer.exchange=best transfer.exchange_every=5 agent.learning_starts=200",
        "exchange_shared_replay_sarsa": "agent=sarsa transfer.exchange=shared_replay transfer.exchange_every=5",
        "exchange_best_qlearning": "agent=qlearning transfer.exchange=best transfer.exchange_every=5",
        "curriculum_nested": "agent=sarsa curriculum=nested curriculum.stages.0.steps=600 "
        "curriculum.stages.1.steps=600 total_steps=1200",
    }.items()
}
# A run stopped at 600 steps, then resumed to 1200: must equal the run made in one go.
RESUMED = ["agent.learning_starts=200", "mode=cooperative"]
SKIPPED_NAMES = {"train.log", "hydra.yaml", "overrides.yaml"}


# Paths are written into files (and into the curriculum cache's keys): every recording is made here.
WORK_DIR = Path(tempfile.gettempdir()) / "dqn_transfer_reference_runs"


class ReferenceRunError(Exception):
    """A recording that cannot be made: its message is one line for the user (or a failed run's stderr)."""


def record(out: Path) -> None:
    """Run the set in :data:`WORK_DIR`, digest its files, and move it to ``out`` (a new directory)."""
    if out.exists():
        raise ReferenceRunError(f"{out} exists: choose a new directory for the recording")
    try:
        WORK_DIR.mkdir()
    except FileExistsError:
        raise ReferenceRunError(
            f"{WORK_DIR} exists: another recording is under way (or remove what a stopped one left)"
        ) from None
    try:
        record_into(WORK_DIR)
        write_digests(WORK_DIR)
        shutil.move(WORK_DIR, out)
    finally:
        shutil.rmtree(WORK_DIR, ignore_errors=True)
    print(f"recorded into {out}")


def record_into(out: Path) -> None:
    """Every run of :data:`RUNS`, the resumed pair, an export and a played GIF, inside ``out``."""
    common = [f"transfer.cache_dir={out / 'pretrained'}", f"curriculum.cache_dir={out / 'curriculum'}"]
    for name, overrides in RUNS.items():
        run(TRAIN + SMALL + overrides + common + [f"hydra.run.dir=runs/{name}"], out, name)
    resumed = ["hydra.run.dir=runs/resumed"]
    run(TRAIN + [*SMALL[:-2], "progress=false", "total_steps=600"] + RESUMED + common + resumed, out, "resumed (1/2)")
    run(TRAIN + ["resume=true", "total_steps=1200"] + resumed, out, "resumed (2/2)")
    run(TRAIN + SMALL + RESUMED + common + ["hydra.run.dir=runs/resumed_in_one_go"], out, "resumed_in_one_go")
    ckpt = [sys.executable, "-m", "dqn_transfer.cli.ckpt"]
    run(ckpt + ["export", "runs/default", "exported"], out, "export")
    play = [sys.executable, "-m", "dqn_transfer.cli.play", "runs/replicas_sarsa/seed_1-map_7"]
    run(play + ["--episodes", "2", "--gif", "played.gif"], out, "play")


def run(command: list[str], cwd: Path, name: str) -> None:
    """One command in ``cwd``; a failure raises with the tail of its stderr."""
    print(f"[{name}]", " ".join(command[3:]), flush=True)
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if done.returncode:
        raise ReferenceRunError(f"{name} failed ({done.returncode}):\n{done.stderr[-3000:]}")


def digest(path: Path) -> str:
    """A file's SHA-256; ``metrics.jsonl`` without its lines' ``wall_time``."""
    data = path.read_bytes()
    if path.name == "metrics.jsonl":
        lines = [json.loads(line) for line in data.decode().splitlines()]
        data = "\n".join(json.dumps({k: v for k, v in line.items() if k != "wall_time"}) for line in lines).encode()
    return hashlib.sha256(data).hexdigest()


def write_digests(out: Path) -> None:
    """``out/DIGESTS.txt``: one ``<sha256>  <path>`` line per file, but those that hold a clock or a process."""
    files = sorted(
        p
        for p in out.rglob("*")
        if p.is_file()
        and p.name not in SKIPPED_NAMES
        and "tfevents" not in p.name
        and ".lock" not in p.name
        and p.name != "DIGESTS.txt"
    )
    lines = [f"{digest(p)}  {p.relative_to(out)}" for p in files]
    (out / "DIGESTS.txt").write_text("\n".join(lines) + "\n")
    print(f"{len(lines)} files digested into {out / 'DIGESTS.txt'}")


def compare(a: Path, b: Path) -> int:
    """Print the files whose digests differ between two recordings, or that only one has; 1 if any, else 0."""

    def read(root: Path) -> dict[str, str]:
        return {
            name: sha for sha, name in (line.split("  ", 1) for line in (root / "DIGESTS.txt").read_text().splitlines())
        }

    left, right = read(a), read(b)
    different = sorted(n for n in left.keys() & right.keys() if left[n] != right[n])
    only = sorted(left.keys() ^ right.keys())
    for name in different:
        print("differs:", name)
    for name in only:
        print("only in", a if name in left else b, ":", name)
    print(f"{len(left.keys() & right.keys())} files in both, {len(different)} different, {len(only)} in one only")
    return 1 if different or only else 0
