"""What `python -m build` ships: the wheel carries every module of the package, the config groups of
``conf/`` (as ``dqn_transfer/conf/``: an installed package finds its configs from any directory) and
``py.typed`` (type checkers read its hints), the console scripts of pyproject.toml and the version of
``dqn_transfer.__version__``; the sdist carries the README, the LICENSE and the config groups.

Built for real (not read from setuptools' metadata) because what matters is the files in the archives;
``--no-isolation`` builds with the installed setuptools, so the test needs no download and takes seconds."""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

import dqn_transfer
from dqn_transfer.config import CONFIG_DIR

if sys.version_info >= (3, 11):
    import tomllib
else:  # mypy's own dependency there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
# The config groups as the checkout holds them (conf/ at the root) and their place in the wheel.
CONF = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "conf").rglob("*.yaml"))
WHEEL_CONF = ["dqn_transfer/" + name for name in CONF]
MODULES = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "dqn_transfer").rglob("*.py"))


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("build")
    out = tmp_path_factory.mktemp("dist")
    done = subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return out


def test_the_editable_install_reads_the_checkouts_conf() -> None:
    """The tests run on ``pip install -e .`` (README, CI): its configs are the checkout's ``conf/``."""
    assert CONFIG_DIR == ROOT / "conf"
    assert len(CONF) > 50 and "conf/config.yaml" in CONF  # the folder the wheel tests below compare with


def test_the_wheel_carries_every_module_and_config_and_finds_them_from_elsewhere(dist: Path, tmp_path: Path) -> None:
    """The wheel holds every module of ``dqn_transfer/`` (pyproject.toml lists the packages, ``conf/`` being
    mapped into one) and every config of ``conf/`` under ``dqn_transfer/conf/``; unpacked as an install
    lays it out and imported from another directory, its ``CONFIG_DIR`` is its own ``dqn_transfer/conf/``."""
    (wheel,) = dist.glob("*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        archive.extractall(tmp_path / "site")
    assert "dqn_transfer/conf/config.yaml" in names
    assert [n for n in WHEEL_CONF if n not in names] == []
    assert [n for n in MODULES if n not in names] == []
    where = subprocess.run(
        [sys.executable, "-c", "from dqn_transfer.config import CONFIG_DIR; print(CONFIG_DIR)"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(tmp_path / "site")},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()) == tmp_path / "site" / "dqn_transfer" / "conf"


@pytest.mark.slow
def test_wheel_carries_types_scripts_and_version(dist: Path) -> None:
    (wheel,) = dist.glob("*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        (metadata,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        meta = archive.read(metadata).decode()
        entry_points = archive.read(metadata.replace("METADATA", "entry_points.txt")).decode()
    assert "dqn_transfer/py.typed" in names
    assert f"Version: {dqn_transfer.__version__}\n" in meta
    assert "License-Expression: MIT" in meta
    cff = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert f"\nversion: {dqn_transfer.__version__}\n" in cff  # CITATION.cff repeats the version
    with open(ROOT / "pyproject.toml", "rb") as file:
        scripts = tomllib.load(file)["project"]["scripts"]
    for script, target in scripts.items():
        assert f"{script} = {target}" in entry_points, script


@pytest.mark.slow
def test_sdist_carries_readme_license_and_configs(dist: Path) -> None:
    (sdist,) = dist.glob("*.tar.gz")
    with tarfile.open(sdist) as archive:
        top = archive.getnames()[0].split("/")[0]
        names = {name.removeprefix(top + "/") for name in archive.getnames()}
    assert {"README.md", "LICENSE", "pyproject.toml", "dqn_transfer/py.typed"} <= names
    assert [n for n in CONF if n not in names] == []
