"""Self-describing, pickle-free checkpoints: one ``agent_{i}.safetensors`` file per agent.

A checkpoint holds tensors only, plus a JSON ``meta`` string under the safetensors metadata key
``"meta"``. The caller supplies the meta; by convention (what ``list`` shows and what
:func:`check_compatible` reads) it has ``algorithm``, ``obs_layout``, ``num_actions``, ``network``,
``env`` (with ``size``), ``mode``, ``steps``, ``episodes`` and ``last_eval`` (the last greedy evaluation,
e.g. ``{"team_return": ..., "success_rate": ...}``). Saving adds ``format_version``, ``kind`` and
``digest``, a SHA-256 over the tensors, so a copied file is complete on its own and a damaged one is
detected.

Why so strict on loading: checkpoints are shared between colleagues, and a pickle (what ``torch.save``
writes) runs arbitrary code when loaded. So nothing here ever calls ``torch.load`` or ``pickle``; a
file is sniffed first and refused when it looks like a pickle or a PyTorch zip, and every other
problem (missing, truncated, foreign, newer, tampered) is a :class:`CheckpointError` with one line
naming the file and the problem.

Tensors are numpy arrays on both sides (a checkpoint is read and written without torch). Resume state
(optimizer, replay, RNG, counters) uses the same container through :func:`save_training_state` /
:func:`load_training_state`.
Writes are atomic (temp file in the same directory, fsync, ``os.replace``), so a killed run never
leaves a half-written file under the final name.

Inspect files from the command line with ``dqn-transfer-ckpt list|show|verify PATH``
(:mod:`dqn_transfer.cli.ckpt`).
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import safetensors
import safetensors.numpy

from dqn_transfer.enums import Algorithm
from dqn_transfer.storage.run_dir import AGENT_FILE_GLOB, CHECKPOINTS_DIR, RunDir, natural_key

FORMAT_VERSION = 1
META_KEY = "meta"
AGENT_KIND = "agent"
TRAINING_STATE_KIND = "training_state"

_KIND_NAMES = {AGENT_KIND: "an agent checkpoint", TRAINING_STATE_KIND: "a training-state file"}
_PICKLE_SUFFIXES = {".pt", ".pth", ".pkl", ".pickle", ".ckpt"}
_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's default container: a zip holding a pickle
_PICKLE_PROTO = 0x80  # first byte of a pickle written with protocol >= 2
_HEADER_LEN_BYTES = 8  # safetensors: little-endian u64 header length, then the JSON header


class CheckpointError(Exception):
    """A checkpoint cannot be written, read or used; the message is one user-facing line."""


@dataclass(frozen=True)
class CheckpointInfo:
    """What a verified file contains, without decoding its tensors into a framework."""

    path: Path
    meta: dict[str, Any]
    tensors: dict[str, tuple[str, list[int]]]  # name -> (safetensors dtype, shape)
    size_bytes: int


# ---------------------------------------------------------------------------------------------
# Writing


def encode_agent_checkpoint(tensors: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> bytes:
    """One agent's arrays and meta as the bytes of its safetensors file (``meta`` is not modified)."""
    return _encode(tensors, meta, AGENT_KIND)


def encode_training_state(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> bytes:
    """Resume state, numpy arrays plus JSON meta (no pickle), as the bytes of its file."""
    return _encode(arrays, meta, TRAINING_STATE_KIND)


def save_agent_checkpoint(path: str | os.PathLike, tensors: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> None:
    """Atomically write one agent's checkpoint file."""
    atomic_write(Path(path), encode_agent_checkpoint(tensors, meta))


def save_training_state(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> None:
    """Atomically write a resume-state file."""
    atomic_write(Path(path), encode_training_state(arrays, meta))


def _encode(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any], kind: str) -> bytes:
    # The digest is computed from the serialized tensors (name, dtype, shape, bytes as stored), so
    # the reader checks exactly what is on disk, whatever framework wrote it. Serializing twice
    # costs little next to the training that produced the tensors.
    tensors = {name: np.ascontiguousarray(array) for name, array in arrays.items()}
    digest = tensor_digest(safetensors.deserialize(safetensors.numpy.save(tensors)))
    full_meta = {**meta, "format_version": FORMAT_VERSION, "kind": kind, "digest": digest}
    try:
        meta_json = json.dumps(full_meta, default=_json_default)
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"{kind} meta is not JSON-serialisable ({e})") from None
    return safetensors.numpy.save(tensors, metadata={META_KEY: meta_json})


def _json_default(value: Any) -> Any:
    """Let numpy scalars/arrays (e.g. eval metrics) into the JSON meta as plain numbers/lists."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` so that ``path`` holds either the old file or the complete new one."""
    atomic_write_all({Path(path): data})


def atomic_write_all(files: Mapping[Path, bytes]) -> None:
    """Replace several files so that a failed write (disk full, a killed writer) changes none of them.

    Every new file is first written and fsync'ed under a temporary name beside its target; only when
    all of them are on disk are they renamed over the old ones, in the given order (so the file
    named last, e.g. the resume state, is replaced last). A failure in the first phase removes the
    temporary files and leaves every old file as it was.
    """
    staged: dict[Path, Path] = {}
    try:
        for path, data in files.items():
            path.parent.mkdir(parents=True, exist_ok=True)
            # Not tempfile.mkstemp: its 0600 mode would make shared checkpoints unreadable to others.
            tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            staged[path] = tmp
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        for path, tmp in staged.items():
            os.replace(tmp, path)
        for directory in {path.parent for path in staged}:  # make the renames themselves durable
            dir_fd = os.open(directory, os.O_RDONLY)
            try:
                os.fsync(dir_fd)
            finally:
                os.close(dir_fd)
    except OSError as e:
        failed = e.filename or next(iter(files), "")
        raise CheckpointError(f"{failed}: cannot write ({e.strerror or e}); the previous files are kept") from None
    finally:
        for tmp in staged.values():
            if os.path.exists(tmp):
                os.unlink(tmp)


# ---------------------------------------------------------------------------------------------
# Reading


def tensor_digest(entries: list[tuple[str, dict[str, Any]]]) -> str:
    """SHA-256 over tensors sorted by name: each name, dtype and shape, then its raw bytes.

    ``entries`` is :func:`safetensors.deserialize`'s output. Dtype and shape fix each tensor's byte
    length, so the concatenation is unambiguous.
    """
    h = hashlib.sha256()
    for name, entry in sorted(entries, key=lambda e: e[0]):
        h.update(json.dumps([name, entry["dtype"], list(entry["shape"])]).encode() + b"\n")
        h.update(entry["data"])
    return h.hexdigest()


def verify_checkpoint(path: str | os.PathLike, kind: str | None = None) -> CheckpointInfo:
    """Check a file completely (format, meta, digest) without decoding or unpickling anything.

    ``kind`` (``"agent"`` or ``"training_state"``), when given, must match the file's.
    """
    return _read(Path(path), kind)[0]


def load_agent_checkpoint(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Verified arrays and meta of one agent checkpoint; see :func:`verify_checkpoint`."""
    return _load(Path(path), AGENT_KIND)


def load_training_state(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Verified arrays and meta written by :func:`save_training_state`."""
    return _load(Path(path), TRAINING_STATE_KIND)


def read_meta(path: str | os.PathLike) -> dict[str, Any]:
    """A checkpoint's meta from its header alone: no tensor is read, nor verified (a loader does both)."""
    path = Path(path)
    try:
        with path.open("rb") as file:
            head = file.read(_HEADER_LEN_BYTES)
            data = head + file.read(int.from_bytes(head, "little")) if len(head) == _HEADER_LEN_BYTES else head
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read checkpoint ({e.strerror})") from None
    return _parse_meta(path, _parse_header(path, data))


def _load(path: Path, kind: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Verified arrays and meta of a ``kind`` file."""
    info, data = _read(path, kind)
    try:
        return safetensors.numpy.load(data), info.meta
    except safetensors.SafetensorError as e:
        raise CheckpointError(f"{path}: cannot decode tensors ({e})") from None


def _read(path: Path, kind: str | None) -> tuple[CheckpointInfo, bytes]:
    """Read, sniff and fully verify ``path``; every failure is one CheckpointError line."""
    data = _read_bytes(path)
    header = _parse_header(path, data)
    meta = _parse_meta(path, header)
    if kind is not None and meta.get("kind", kind) != kind:
        raise CheckpointError(
            f"{path}: is {_KIND_NAMES.get(meta['kind'], repr(meta['kind']))}, not {_KIND_NAMES[kind]}"
        )
    try:
        entries = safetensors.deserialize(data)
    except safetensors.SafetensorError as e:
        raise CheckpointError(f"{path}: corrupt or truncated safetensors data ({e})") from None
    if tensor_digest(entries) != meta.get("digest"):
        raise CheckpointError(f"{path}: tensor digest mismatch: the file is corrupt or was modified")
    tensors = {name: (e["dtype"], list(e["shape"])) for name, e in sorted(entries, key=lambda e: e[0])}
    return CheckpointInfo(path, meta, tensors, len(data)), data


def _read_bytes(path: Path) -> bytes:
    refusal = (
        f"{path} is a pickle/PyTorch file, not a safetensors checkpoint; refusing to load it (pickles can run code)"
    )
    if not path.exists():
        raise CheckpointError(f"{path}: no such checkpoint file")
    if path.is_dir():
        raise CheckpointError(
            f"{path}: is a directory, not a checkpoint file "
            "(give agent_<i>.safetensors, or use the CLI on the directory)"
        )
    if path.suffix.lower() in _PICKLE_SUFFIXES:
        raise CheckpointError(refusal)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read checkpoint ({e.strerror})") from None
    if not data:
        raise CheckpointError(f"{path}: empty file, not a checkpoint")
    if data.startswith(_ZIP_MAGIC) or (data[0] == _PICKLE_PROTO and not _looks_like_safetensors(data)):
        raise CheckpointError(refusal)
    return data


def _looks_like_safetensors(data: bytes) -> bool:
    """A safetensors header length is a plausible u64 and the JSON header opens with ``{``.

    Needed because a valid header length can itself start with byte 0x80 (e.g. 128 bytes).
    """
    if len(data) <= _HEADER_LEN_BYTES:
        return False
    n = int.from_bytes(data[:_HEADER_LEN_BYTES], "little")
    return n <= len(data) - _HEADER_LEN_BYTES and data[_HEADER_LEN_BYTES : _HEADER_LEN_BYTES + 1] == b"{"


def _parse_header(path: Path, data: bytes) -> dict[str, Any]:
    if len(data) < _HEADER_LEN_BYTES:
        raise CheckpointError(f"{path}: truncated file ({len(data)} bytes), not a safetensors checkpoint")
    n = int.from_bytes(data[:_HEADER_LEN_BYTES], "little")
    if n > len(data) - _HEADER_LEN_BYTES:
        raise CheckpointError(
            f"{path}: truncated or not a safetensors file (header length {n} exceeds the file size {len(data)})"
        )
    try:
        header = json.loads(data[_HEADER_LEN_BYTES : _HEADER_LEN_BYTES + n])
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise CheckpointError(f"{path}: invalid safetensors header (not JSON); not a safetensors checkpoint") from None
    if not isinstance(header, dict):
        raise CheckpointError(f"{path}: invalid safetensors header (not a JSON object)")
    return header


def _parse_meta(path: Path, header: dict[str, Any]) -> dict[str, Any]:
    metadata = header.get("__metadata__")
    if not isinstance(metadata, dict) or META_KEY not in metadata:
        raise CheckpointError(f"{path}: no '{META_KEY}' in the safetensors metadata; not a dqn_transfer checkpoint")
    try:
        meta = json.loads(metadata[META_KEY])
    except (TypeError, json.JSONDecodeError):
        raise CheckpointError(f"{path}: the '{META_KEY}' metadata is not valid JSON") from None
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path}: the '{META_KEY}' metadata is not a JSON object")
    version = meta.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise CheckpointError(f"{path}: meta has no integer format_version; not a dqn_transfer checkpoint")
    if version > FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: format_version {version} is newer than this dqn_transfer "
            f"supports ({FORMAT_VERSION}); upgrade dqn_transfer to load it"
        )
    if not isinstance(meta.get("digest"), str):
        raise CheckpointError(f"{path}: meta has no tensor digest; cannot verify the file")
    return meta


# ---------------------------------------------------------------------------------------------
# Compatibility


def check_compatible(meta: Mapping[str, Any], expected: Mapping[str, Any]) -> None:
    """Refuse a checkpoint that does not fit the run, naming the first mismatch.

    ``expected`` may hold ``algorithm`` (compared by family: tabular vs DQN, since Double DQN can
    continue a DQN network), ``obs_layout``, ``num_actions``, ``size`` (map side, read from
    ``meta["env"]["size"]`` or ``meta["size"]``; skipped if the checkpoint does not record it) and
    any other key, compared for equality with ``meta[key]``.
    """
    for key, want in expected.items():
        if key == "size":
            env = meta.get("env")
            have = env.get("size") if isinstance(env, Mapping) else None
            have = meta.get("size") if have is None else have
            if have is not None and int(have) != int(want):
                raise CheckpointError(f"checkpoint was trained on a {have}x{have} map; this run uses {want}x{want}")
            continue
        if key not in meta:
            raise CheckpointError(f"checkpoint meta does not record {key!r}; cannot check compatibility")
        have = meta[key]
        if key == "algorithm":
            fam_have, fam_want = _family(have), _family(want)
            if fam_have != fam_want:
                raise CheckpointError(
                    f"checkpoint holds a {fam_have} agent ({have}); this run uses a {fam_want} agent ({want})"
                )
        elif key == "obs_layout":
            if _layout_str(have) != _layout_str(want):
                raise CheckpointError(
                    f"checkpoint obs_layout [{_layout_str(have)}] differs from this run's [{_layout_str(want)}]"
                )
        elif key == "num_actions":
            if int(have) != int(want):
                raise CheckpointError(f"checkpoint has {have} actions; this run has {want}")
        elif _normalise(have) != _normalise(want):
            raise CheckpointError(f"checkpoint has {key}={have!r}; this run expects {want!r}")


def _family(algorithm: str) -> str:
    try:
        return Algorithm(str(algorithm)).family
    except ValueError:  # a stranger's algorithm: compared by its own name
        return str(algorithm)


def _layout_str(layout: Any) -> str:
    return ", ".join(f"{name}:{int(size)}" for name, size in layout)


def _normalise(value: Any) -> Any:
    """Compare JSON-read values with in-memory ones (tuples come back from JSON as lists)."""
    return json.loads(json.dumps(value, default=_json_default))


# ---------------------------------------------------------------------------------------------
# Finding files and the command line


def find_checkpoints(path: str | os.PathLike) -> list[Path]:
    """Agent checkpoints under ``path``: a file, a run dir (``run/checkpoints``), a checkpoints dir, or a
    run of replicas (every replica's, replica by replica).

    Sorted by agent index (``agent_10`` after ``agent_2``). A file is returned as is, so loading it
    gives the precise refusal (pickle, not safetensors, ...).
    """
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: no such file or directory")
    if path.is_file():
        return [path]
    replicas = RunDir(path).replica_dirs()
    if replicas:
        return [file for replica in replicas for file in find_checkpoints(replica)]
    directory = path / CHECKPOINTS_DIR if (path / CHECKPOINTS_DIR).is_dir() else path
    files = sorted(directory.glob(AGENT_FILE_GLOB), key=lambda file: natural_key(file.name))
    if not files:
        raise CheckpointError(f"{directory}: no {AGENT_FILE_GLOB} checkpoints found")
    return files


if __name__ == "__main__":  # the command line moved to dqn_transfer.cli.ckpt; say so instead of doing nothing
    raise SystemExit(
        "error: dqn_transfer.storage.checkpoint is a library module; inspect checkpoints with "
        "`dqn-transfer-ckpt list|show|verify PATH` (or `python -m dqn_transfer.cli.ckpt`)"
    )
