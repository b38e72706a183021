"""Compiled kernels without a writable cache directory: one notice, and they still run (compiled in the
process instead of loaded from disk)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from dqn_transfer import compiled

PROGRAM = """
import numpy as np
from dqn_transfer.compiled import CACHE, kernel

def total(values):
    sum = 0
    for value in values:
        sum += value
    return sum

print(CACHE, kernel(total)(np.arange(5)))
"""


def run(tmp_path: Path, cache_dir: Path) -> subprocess.CompletedProcess:
    program = tmp_path / "program.py"
    program.write_text(PROGRAM)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    return subprocess.run([sys.executable, str(program)], capture_output=True, text=True, env=env, timeout=120)


def test_without_a_writable_cache_the_kernels_run_after_one_notice(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    done = run(tmp_path, blocker / "cache")  # a directory cannot be made inside a file, not even by root
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "10"]
    notice = done.stderr.strip().splitlines()
    assert len(notice) == 1 and "NUMBA_CACHE_DIR" in notice[0], done.stderr


def test_with_a_writable_cache_the_kernels_are_kept_there(tmp_path):
    done = run(tmp_path, tmp_path / "cache")
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert done.stdout.split() == ["True", "10"]
    kept = sorted(path.suffix for path in (tmp_path / "cache").rglob("program.total-*"))
    assert kept == [".nbc", ".nbi"]  # numba's index and compiled code


def test_a_change_to_any_file_with_a_kernel_starts_a_new_cache_and_removes_the_old(tmp_path, monkeypatch):
    """numba checks only a kernel's own file, yet a kernel's compiled code holds the kernels it calls from
    other files: the cache directory is named by a hash of all the files that hold kernels."""
    package = tmp_path / "package"
    package.mkdir()
    (package / "rules.py").write_text("@kernel\ndef step(): pass\n")
    (package / "docs.py").write_text("def describe(): pass\n")
    monkeypatch.setattr(compiled, "PACKAGE", package)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    first = compiled.cache_directory()
    (package / "docs.py").write_text("def describe(): return 'no kernel here'\n")
    assert compiled.cache_directory() == first
    (package / "rules.py").write_text("@kernel\ndef step(): return 1\n")
    second = compiled.cache_directory()
    assert second != first and second.is_dir() and not first.exists()
