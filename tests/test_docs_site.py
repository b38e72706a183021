"""The docs site builds strictly (any warning fails: a broken link or anchor, a docstring mkdocstrings
cannot read, a name it cannot find), with a page per console script and per subpackage."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def test_links_map_onto_the_site() -> None:
    """The repository's relative links land on the site's pages: the README's ``docs/x.md`` is ``x.md``
    beside it, a guide page's ``../results/REPORT.md`` is the site's ``results/REPORT.md``."""
    pytest.importorskip("mkdocs")
    from mkdocs_hooks import site_path

    class _File:
        def __init__(self, src: Path, uri: str) -> None:
            self.abs_src_path, self.src_uri = str(src), uri

    class _Page:
        def __init__(self, src: Path, uri: str) -> None:
            self.file = _File(src, uri)

    docs = str(ROOT / "docs")
    home = _Page(ROOT / "README.md", "index.md")
    guide = _Page(ROOT / "docs" / "reproducing.md", "reproducing.md")
    assert site_path(home, "docs/game.md#maps", docs) == "game.md#maps"  # type: ignore[arg-type]
    assert site_path(home, "results/REPORT.md", docs) == "results/REPORT.md"  # type: ignore[arg-type]
    assert site_path(guide, "../results/VERDICT_RULES.md", docs) == "results/VERDICT_RULES.md"  # type: ignore[arg-type]
    assert site_path(guide, "sweeps.md", docs) == "sweeps.md"  # type: ignore[arg-type]
    assert site_path(guide, "https://example.org/a.md", docs) is None  # type: ignore[arg-type]
    assert site_path(guide, "#a-heading", docs) is None  # type: ignore[arg-type]


@pytest.mark.slow
def test_mkdocs_build_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings_handlers.python")
    from mkdocs_hooks import console_scripts, subpackages

    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    home = (site / "index.html").read_text(encoding="utf-8")
    assert "Two commands" in home  # the README is the home page
    for script in console_scripts():
        page = (site / "cli" / script / "index.html").read_text(encoding="utf-8")
        assert f"usage: {script}" in page, script  # its own --help, under its own name
    for name in ["dqn_transfer", *subpackages()]:
        assert (site / "api" / name / "index.html").is_file(), name
    assert (site / "results" / "v2" / "VERDICT_RULES" / "index.html").is_file()  # the second edition
    assert (site / "results" / "v1" / "REPORT" / "index.html").is_file()  # the first edition
