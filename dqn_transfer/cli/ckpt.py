"""``dqn-transfer-ckpt list|show|verify PATH``: inspect checkpoints (a file, a run dir or a checkpoints dir);
``dqn-transfer-ckpt export RUN_DIR OUT_DIR``: the team as a folder to share, with its model card
(:mod:`dqn_transfer.sharing.model_card`).

Every file is verified (format, meta, digest) before anything is shown; a bad file is one ``error:``
line and exit code 1, never a traceback, and nothing is ever unpickled.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping

from dqn_transfer.cli.console import exit_with
from dqn_transfer.sharing.model_card import ExportError, export_team
from dqn_transfer.storage.checkpoint import CheckpointError, CheckpointInfo, find_checkpoints, verify_checkpoint
from dqn_transfer.storage.run_dir import RunDir


def _format_list_row(info: CheckpointInfo, replicas: bool) -> str:
    meta = info.meta
    last_eval = meta.get("last_eval")
    eval_return = last_eval.get("team_return") if isinstance(last_eval, Mapping) else None
    eval_text = "-" if eval_return is None else f"{float(eval_return):.2f}"
    name = f"{info.path.parent.parent.name}/{info.path.name}" if replicas else info.path.name  # seed_3/agent_0...
    return (
        f"{name}  algorithm={meta.get('algorithm', '-')}  steps={meta.get('steps', '-')}"
        f"  episodes={meta.get('episodes', '-')}  eval_return={eval_text}"
        f"  size={_human_size(info.size_bytes)}"
    )


def _format_show(info: CheckpointInfo) -> str:
    lines = [f"# {info.path}", json.dumps(info.meta, indent=2), "tensors:"]
    lines += [f"  {name}  {dtype}  {shape}" for name, (dtype, shape) in info.tensors.items()]
    return "\n".join(lines)


def _human_size(n_bytes: int) -> str:
    if n_bytes < 1024:
        return f"{n_bytes} B"
    size = n_bytes / 1024
    for unit in ("KiB", "MiB"):
        if size < 1024:
            return f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} GiB"


def main(argv: list[str] | None = None) -> int:
    """``list`` / ``show`` / ``verify`` checkpoints (exit 1 with one ``error:`` line per bad file), or
    ``export`` a team (exit 1 with one ``error:`` line, nothing written)."""
    parser = argparse.ArgumentParser(
        prog="dqn-transfer-ckpt", description="Inspect dqn_transfer safetensors checkpoints, or export a team."
    )
    parser.add_argument("command", choices=["list", "show", "verify", "export"])
    parser.add_argument(
        "path",
        help="a checkpoint file, a run directory or a checkpoints directory (export: the "
        "run, replica or agent file to export)",
    )
    parser.add_argument(
        "out_dir",
        nargs="?",
        metavar="OUT_DIR",
        help="export: a new (or empty) folder for the agents' files and the model card",
    )
    args = parser.parse_args(argv)
    if (args.command == "export") != (args.out_dir is not None):
        print("error: OUT_DIR goes with export only: dqn-transfer-ckpt export RUN_DIR OUT_DIR", file=sys.stderr)
        return 1
    if args.command == "export":
        try:
            out_dir = export_team(args.path, args.out_dir)
        except ExportError as e:
            print(f"error: {e}", file=sys.stderr)
            return 1
        print(f"exported {args.path} to {out_dir}: {', '.join(sorted(p.name for p in out_dir.iterdir()))}")
        return 0

    try:
        files = find_checkpoints(args.path)
    except CheckpointError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    failed, replicas = False, bool(RunDir(args.path).replica_dirs())
    for file in files:
        try:
            info = verify_checkpoint(file)
        except CheckpointError as e:
            print(f"error: {e}", file=sys.stderr)
            failed = True
            continue
        if args.command == "list":
            print(_format_list_row(info, replicas))
        elif args.command == "show":
            print(_format_show(info))
        else:
            print(f"OK {file}")
    return 1 if failed else 0


def run() -> None:
    """Console-script entry: ``main`` with a quiet exit when the reader of stdout goes away."""
    exit_with(main)


if __name__ == "__main__":
    run()
