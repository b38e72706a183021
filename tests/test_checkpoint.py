"""Checkpoint files: round trip, atomic writes, and every refusal (above all: never unpickle)."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import safetensors.torch
import torch

from dqn_transfer.cli import ckpt as ckpt_cli
from dqn_transfer.config import AgentConfig, TrainConfig
from dqn_transfer.enums import Algorithm
from dqn_transfer.envs.settings import EnvConfig
from dqn_transfer.storage import checkpoint
from dqn_transfer.storage.checkpoint import (
    FORMAT_VERSION,
    CheckpointError,
    check_compatible,
    find_checkpoints,
    load_agent_checkpoint,
    load_training_state,
    save_agent_checkpoint,
    save_training_state,
    verify_checkpoint,
)
from dqn_transfer.storage.run_dir import RunDir
from dqn_transfer.training.plan import plan_run
from dqn_transfer.training.trainer import Trainer

REPO = Path(__file__).resolve().parents[1]


def make_meta() -> dict:
    return {
        "algorithm": "dqn",
        "obs_layout": [["position", 36], ["treasures", 1]],
        "num_actions": 4,
        "network": {"hidden": [64, 64], "obs_dim": 37},
        "env": {"size": 6, "num_treasures": 1},
        "mode": "competitive",
        "steps": 1000,
        "episodes": 17,
        "last_eval": {"team_return": -12.5, "success_rate": 1.0},
    }


def make_tensors() -> dict[str, np.ndarray]:
    return {
        "q.layers.0.weight": np.random.default_rng(0).standard_normal((64, 37), dtype=np.float32),
        "q.layers.0.bias": np.zeros(64, dtype=np.float32),
        "counts": np.arange(5, dtype=np.int64),
    }


@pytest.fixture
def ckpt(tmp_path: Path) -> Path:
    path = tmp_path / "run" / "checkpoints" / "agent_0.safetensors"
    save_agent_checkpoint(path, make_tensors(), make_meta())
    return path


def expect_refusal(path: Path, *fragments: str) -> str:
    with pytest.raises(CheckpointError) as info:
        load_agent_checkpoint(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    for fragment in fragments:
        assert fragment in message
    return message


def write_safetensors(path: Path, metadata: dict[str, str] | None) -> Path:
    path.write_bytes(safetensors.torch.save({"w": torch.ones(2)}, metadata=metadata))
    return path


# ------------------------------------------------------------------ round trips and atomicity


def test_agent_round_trip_keeps_tensors_dtypes_and_meta(ckpt: Path):
    original, meta = make_tensors(), make_meta()
    tensors, loaded_meta = load_agent_checkpoint(ckpt)
    assert tensors.keys() == original.keys()
    for name, tensor in original.items():
        assert tensors[name].dtype == tensor.dtype
        assert np.array_equal(tensors[name], tensor)
    assert tensors["q.layers.0.weight"].dtype == np.float32
    assert tensors["counts"].dtype == np.int64
    assert {k: loaded_meta[k] for k in meta} == meta
    assert loaded_meta["format_version"] == FORMAT_VERSION
    assert loaded_meta["kind"] == "agent"
    assert len(loaded_meta["digest"]) == 64 and int(loaded_meta["digest"], 16) >= 0


def test_save_leaves_caller_meta_alone_and_accepts_numpy_scalars(tmp_path: Path):
    meta = {"algorithm": "dqn", "steps": np.int64(7), "last_eval": {"team_return": np.float32(-2.5)}}
    save_agent_checkpoint(tmp_path / "agent_0.safetensors", make_tensors(), meta)
    assert "digest" not in meta and "format_version" not in meta
    _, loaded = load_agent_checkpoint(tmp_path / "agent_0.safetensors")
    assert loaded["steps"] == 7 and loaded["last_eval"] == {"team_return": -2.5}


def test_training_state_round_trip(tmp_path: Path):
    arrays = {
        "adam.exp_avg": np.linspace(0.0, 1.0, 6, dtype=np.float32).reshape(2, 3),
        "replay.actions": np.array([[0, 3, 2]], dtype=np.int64),
        "replay.terminated": np.array([True, False]),
        "rng.state": np.array([1, 2, 3, 4], dtype=np.uint64),
    }
    meta = {"steps": 1000, "episodes": 17, "rng": {"bit_generator": "PCG64"}}
    save_training_state(tmp_path / "training_state.safetensors", arrays, meta)
    loaded, loaded_meta = load_training_state(tmp_path / "training_state.safetensors")
    assert loaded.keys() == arrays.keys()
    for name, array in arrays.items():
        assert loaded[name].dtype == array.dtype
        np.testing.assert_array_equal(loaded[name], array)
    assert {k: loaded_meta[k] for k in meta} == meta and loaded_meta["kind"] == "training_state"


def test_atomic_write_leaves_only_the_final_file(tmp_path: Path):
    path = tmp_path / "agent_0.safetensors"
    save_agent_checkpoint(path, make_tensors(), make_meta())
    save_agent_checkpoint(path, make_tensors(), {**make_meta(), "steps": 2000})  # overwrite
    assert sorted(os.listdir(tmp_path)) == ["agent_0.safetensors"]
    assert load_agent_checkpoint(path)[1]["steps"] == 2000
    assert path.stat().st_mode & 0o044  # readable by colleagues (umask permitting), unlike mkstemp's 0600


def broken_replace(src, dst):
    raise OSError(28, "No space left on device")


def test_failed_write_leaves_nothing_under_the_final_name(tmp_path: Path, monkeypatch):
    monkeypatch.setattr(os, "replace", broken_replace)
    new = tmp_path / "agent_0.safetensors"
    with pytest.raises(CheckpointError, match="cannot write .*No space left"):
        save_agent_checkpoint(new, make_tensors(), make_meta())
    assert os.listdir(tmp_path) == []  # no final file, no temp file


def test_failed_overwrite_keeps_the_previous_checkpoint(ckpt: Path, monkeypatch):
    before = ckpt.read_bytes()
    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(CheckpointError):
        save_agent_checkpoint(ckpt, make_tensors(), {**make_meta(), "steps": 2000})
    assert ckpt.read_bytes() == before
    assert os.listdir(ckpt.parent) == ["agent_0.safetensors"]


def test_header_length_starting_with_pickle_byte_is_still_loaded(tmp_path: Path):
    # A valid header length can begin with byte 0x80 (e.g. 128 or 384 bytes): the pickle sniff must
    # not refuse it. Grow a padding string in the meta until the header length is 128 mod 256.
    path = tmp_path / "agent_0.safetensors"
    for pad in range(300):
        save_agent_checkpoint(path, {"w": np.ones(1, np.float32)}, {"pad": "x" * pad})
        if path.read_bytes()[0] == 0x80:
            break
    else:
        pytest.fail("no padding gave a header length starting with 0x80")
    tensors, _ = load_agent_checkpoint(path)
    assert np.array_equal(tensors["w"], np.ones(1, np.float32))


# ------------------------------------------------------------------ refusals


def test_refuses_missing_file(tmp_path: Path):
    expect_refusal(tmp_path / "agent_0.safetensors", "no such checkpoint file")


def test_refuses_directory(tmp_path: Path):
    expect_refusal(tmp_path, "is a directory")


class _CreatesFileWhenUnpickled:
    """Pickle bait: unpickling calls open(marker, "w"), i.e. runs code of the file's choosing."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return open, (str(self.marker), "w")


def test_refuses_pickle_without_unpickling_it(tmp_path: Path):
    # The bait is real: unpickling it does create its marker file ...
    proof = tmp_path / "proof"
    pickle.loads(pickle.dumps(_CreatesFileWhenUnpickled(proof))).close()
    assert proof.exists()
    # ... and loading it as a checkpoint must not.
    marker = tmp_path / "pwned"
    path = tmp_path / "agent_0.safetensors"
    path.write_bytes(pickle.dumps(_CreatesFileWhenUnpickled(marker)))
    expect_refusal(path, "is a pickle/PyTorch file", "refusing to load it (pickles can run code)")
    with pytest.raises(CheckpointError):
        verify_checkpoint(path)
    assert not marker.exists()


@pytest.mark.parametrize(
    "name, zipfile",
    [
        ("model.pt", True),  # refused by its extension
        ("agent_0.safetensors", True),  # renamed torch.save zip: refused by its PK magic
        ("agent_0.safetensors", False),  # legacy torch.save: a bare pickle, refused by its 0x80 byte
    ],
)
def test_refuses_torch_save_files(tmp_path: Path, name: str, zipfile: bool):
    path = tmp_path / name
    torch.save(make_tensors(), path, _use_new_zipfile_serialization=zipfile)
    expect_refusal(path, "is a pickle/PyTorch file, not a safetensors checkpoint")


def test_refuses_empty_file(tmp_path: Path):
    path = tmp_path / "agent_0.safetensors"
    path.write_bytes(b"")
    expect_refusal(path, "empty file")


def test_refuses_file_truncated_inside_the_header(ckpt: Path):
    ckpt.write_bytes(ckpt.read_bytes()[:40])
    expect_refusal(ckpt, "truncated or not a safetensors file", "exceeds the file size 40")


def test_refuses_file_truncated_inside_the_tensor_data(ckpt: Path):
    ckpt.write_bytes(ckpt.read_bytes()[:-4])
    expect_refusal(ckpt, "corrupt or truncated safetensors data")


def test_refuses_bit_flipped_tensor_byte(ckpt: Path):
    data = bytearray(ckpt.read_bytes())
    data[-1] ^= 0x01  # last byte of the tensor data
    ckpt.write_bytes(bytes(data))
    expect_refusal(ckpt, "tensor digest mismatch: the file is corrupt or was modified")


def test_refuses_invalid_header_json(tmp_path: Path):
    path = tmp_path / "agent_0.safetensors"
    path.write_bytes((16).to_bytes(8, "little") + b"this is not json")
    expect_refusal(path, "invalid safetensors header")


def test_refuses_safetensors_without_meta(tmp_path: Path):
    path = write_safetensors(tmp_path / "agent_0.safetensors", metadata=None)
    expect_refusal(path, "no 'meta' in the safetensors metadata")


def test_refuses_meta_that_is_not_json(tmp_path: Path):
    path = write_safetensors(tmp_path / "agent_0.safetensors", metadata={"meta": "{not json"})
    expect_refusal(path, "'meta' metadata is not valid JSON")


def test_refuses_newer_format_version(tmp_path: Path):
    meta = json.dumps({"format_version": FORMAT_VERSION + 1, "digest": "0" * 64})
    path = write_safetensors(tmp_path / "agent_0.safetensors", metadata={"meta": meta})
    expect_refusal(path, f"format_version {FORMAT_VERSION + 1} is newer", "upgrade dqn_transfer")


def test_refuses_training_state_as_agent_checkpoint(tmp_path: Path):
    path = tmp_path / "training_state.safetensors"
    save_training_state(path, {"a": np.zeros(2)}, {})
    expect_refusal(path, "is a training-state file, not an agent checkpoint")


def test_training_state_loader_refuses_pickles_too(tmp_path: Path):
    marker = tmp_path / "pwned"
    path = tmp_path / "training_state.safetensors"
    path.write_bytes(pickle.dumps(_CreatesFileWhenUnpickled(marker)))
    with pytest.raises(CheckpointError, match="refusing to load it"):
        load_training_state(path)
    assert not marker.exists()


# ------------------------------------------------------------------ compatibility


def test_check_compatible_accepts_matching_run():
    meta = make_meta()
    check_compatible(
        meta,
        {
            "algorithm": "double_dqn",  # same family as dqn
            "obs_layout": (("position", 36), ("treasures", 1)),  # tuples vs JSON lists
            "num_actions": 4,
            "size": 6,
            "mode": "competitive",
        },
    )


@pytest.mark.parametrize(
    "expected, message",
    [
        ({"size": 8}, "checkpoint was trained on a 6x6 map; this run uses 8x8"),
        (
            {"obs_layout": [("position", 64), ("treasures", 2)]},
            "checkpoint obs_layout [position:36, treasures:1] differs from this run's [position:64, treasures:2]",
        ),
        ({"algorithm": "sarsa"}, "checkpoint holds a dqn agent (dqn); this run uses a tabular agent (sarsa)"),
        ({"num_actions": 5}, "checkpoint has 4 actions; this run has 5"),
        ({"mode": "cooperative"}, "checkpoint has mode='competitive'; this run expects 'cooperative'"),
    ],
)
def test_check_compatible_names_the_mismatch(expected: dict, message: str):
    with pytest.raises(CheckpointError) as info:
        check_compatible(make_meta(), expected)
    assert str(info.value) == message


# ------------------------------------------------------------------ finding files and the CLI


def test_find_checkpoints_from_file_run_dir_and_checkpoints_dir(tmp_path: Path):
    ckpt_dir = tmp_path / "run" / "checkpoints"
    for i in (10, 2, 0):
        save_agent_checkpoint(ckpt_dir / f"agent_{i}.safetensors", {"w": np.ones(1, np.float32)}, {})
    save_training_state(ckpt_dir / "training_state.safetensors", {"a": np.zeros(1)}, {})
    expected = [ckpt_dir / f"agent_{i}.safetensors" for i in (0, 2, 10)]  # natural order
    assert find_checkpoints(tmp_path / "run") == expected
    assert find_checkpoints(ckpt_dir) == expected
    assert find_checkpoints(expected[1]) == [expected[1]]
    with pytest.raises(CheckpointError, match="no such file or directory"):
        find_checkpoints(tmp_path / "missing")
    with pytest.raises(CheckpointError, match="no agent_"):
        find_checkpoints(tmp_path)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "dqn_transfer.cli.ckpt", *args], cwd=REPO, capture_output=True, text=True, timeout=60
    )


def test_cli_list_show_verify_on_a_good_run(ckpt: Path, capsys):
    run_dir = ckpt.parent.parent
    assert ckpt_cli.main(["list", str(run_dir)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("agent_0.safetensors  algorithm=dqn  steps=1000  episodes=17  eval_return=-12.50")

    assert ckpt_cli.main(["show", str(ckpt)]) == 0
    out = capsys.readouterr().out
    assert '"format_version": 1' in out and "q.layers.0.weight  F32  [64, 37]" in out
    assert "counts  I64  [5]" in out

    result = run_cli("verify", str(run_dir))  # once through the real entry point
    assert (result.returncode, result.stdout, result.stderr) == (0, f"OK {ckpt}\n", "")


def test_cli_verify_reports_bad_files_in_one_line_without_traceback(ckpt: Path, tmp_path: Path):
    data = bytearray(ckpt.read_bytes())
    data[-1] ^= 0x01
    ckpt.write_bytes(bytes(data))
    marker = tmp_path / "pwned"
    bait = tmp_path / "bait.safetensors"
    bait.write_bytes(pickle.dumps(_CreatesFileWhenUnpickled(marker)))

    for path, fragment in [
        (ckpt, "tensor digest mismatch"),
        (bait, "refusing to load it"),
        (tmp_path / "missing", "no such file or directory"),
    ]:
        result = run_cli("verify", str(path))
        assert result.returncode == 1
        assert "Traceback" not in result.stderr
        lines = result.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and fragment in lines[0]
    assert not marker.exists()


def test_a_disk_full_during_a_run_keeps_the_previous_checkpoint_whole(tmp_path: Path, monkeypatch):
    """The trainer's checkpoint is several files; the disk fills while the second checkpoint's second
    file is written. Every file on disk must still be the first checkpoint's, verified, and nothing
    half-written may be left (the run ends with the one-line CheckpointError)."""
    layout = "0..T\n....\n....\n1..T"  # two agents, two chests three moves away: episodes of 3 steps
    config = TrainConfig(
        env=EnvConfig(layout=layout, size=4, num_treasures=2, num_traps=0, num_agents=2, complexity=0.0),
        agent=AgentConfig(algorithm=Algorithm.qlearning, lr=0.5),
        total_steps=400,
        eval_every=400,
        eval_episodes=1,
        checkpoint_every=100,
        progress=False,
    )
    run = RunDir(tmp_path / "run")
    temp_files_opened = []
    real_open = os.open

    def filling_disk(path, flags, *args):
        if str(path).endswith(".tmp"):
            temp_files_opened.append(path)
            if len(temp_files_opened) == 5:  # checkpoint 1 wrote 3 files; this is checkpoint 2's 2nd
                raise OSError(28, "No space left on device", str(path))
        return real_open(path, flags, *args)

    monkeypatch.setattr(checkpoint.os, "open", filling_disk)
    with pytest.raises(CheckpointError, match="No space left on device.*previous files are kept"):
        Trainer(plan_run(config), run.path).run()
    files = sorted(p.name for p in run.checkpoints.iterdir())
    assert files == ["agent_0.safetensors", "agent_1.safetensors", "training_state.safetensors"]  # no temp files
    steps = {load_agent_checkpoint(run.agent_checkpoint(i))[1]["steps"] for i in (0, 1)}
    _, state = load_training_state(run.training_state)
    assert steps == {state["counters"]["step"]} and 100 <= state["counters"]["step"] < 200


def test_resuming_from_a_table_key_that_is_no_observation_of_the_game_is_refused_in_one_line(tmp_path: Path):
    """Dense tables number the game's own observations: a resume state whose table holds another
    vector (a game whose observations changed, a file edited) is a CheckpointError naming the file."""
    layout = "0..T\n....\n....\n1..T"
    config = TrainConfig(
        env=EnvConfig(layout=layout, size=4, num_treasures=2, num_traps=0, num_agents=2, complexity=0.0),
        agent=AgentConfig(algorithm=Algorithm.sarsa, lr=0.5),
        total_steps=20,
        eval_every=20,
        eval_episodes=1,
        progress=False,
    )
    run = RunDir(tmp_path / "run")
    Trainer(plan_run(config), run.path).run()
    arrays, meta = load_training_state(run.training_state)
    arrays["agent_0/keys"][0] = 0.0  # on no cell
    save_training_state(run.training_state, arrays, meta)
    resumed = dataclasses.replace(config, resume=True, total_steps=40)
    with pytest.raises(CheckpointError, match=r"training_state.safetensors: \[0.0, .* is no observation of this game"):
        Trainer(plan_run(resumed), run.path).run()
