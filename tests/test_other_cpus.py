"""The float-sensitive tests again under other CPUs' BLAS kernels, so a test whose outcome depends on this
machine's rounding fails here, not on the next machine.

numpy's OpenBLAS picks its kernels for the CPU it runs on (a sum's order, fused multiply-adds), and
``OPENBLAS_CORETYPE`` makes it take another CPU's, read when the library loads: hence a subprocess. Haswell's
kernels (AVX2) run on any x86-64 machine of the last decade, and differ from an AVX-512 machine's default.
On them the suite once failed three tests that passed on an Intel Xeon: the VDN engine test (a gradient
near Adam's eps) and the committed budgets (a slope at its threshold).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
TESTS = Path(__file__).resolve().parent
FLOAT_SENSITIVE = [
    f"{TESTS / 'test_vdn.py'}::test_each_engines_vdn_step_is_autograd_of_the_summed_loss",
    str(TESTS / "test_budget.py"),
    f"{TESTS / 'test_study.py'}::"
    "test_the_committed_budgets_come_from_the_committed_pilot_data_and_one_experiments_pilot_keeps_the_rest",
]


def test_float_sensitive_tests_pass_on_another_cpus_kernels():
    env = {**os.environ, "OPENBLAS_CORETYPE": "Haswell"}
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", *FLOAT_SENSITIVE],
        env=env,
        capture_output=True,
        text=True,
        cwd=TESTS.parent,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
