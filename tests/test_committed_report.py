"""The committed third-edition report, ``results/REPORT.md``, is written again from its committed data alone,
byte for byte (the longest single test of the suite, about a minute: it replays the random team on every map,
most of it on LBF's Python engine, so it sits in a file collected early, where the parallel workers share the
rest of the suite around it)."""

import shutil
from pathlib import Path

from conftest import missing_beside

from dqn_transfer.cli import report as report_cli


def test_the_committed_third_edition_report_is_regenerated_from_the_committed_data(tmp_path, capsys):
    # results/REPORT.md is what `dqn-transfer-report results/v3 --out results` writes from results/v3's data,
    # tuning tables, maps, stage times and its repeat's record alone, byte for byte, its figures beside it.
    results = Path(__file__).resolve().parents[1] / "results"
    study_dir = tmp_path / "study"
    for part in ("data", "tuning"):
        shutil.copytree(results / "v3" / part, study_dir / part, ignore=shutil.ignore_patterns("runs", "logs"))
    for part in ("maps.json", "maps.md", "stages.json", "repeat.json"):
        shutil.copy(results / "v3" / part, study_dir / part)
    out = tmp_path / "elsewhere"
    assert report_cli.main([str(study_dir), "--out", str(out)]) == 0
    assert f"wrote {out / 'REPORT.md'}" in capsys.readouterr().out
    assert (out / "REPORT.md").read_bytes() == (results / "REPORT.md").read_bytes()
    figures = sorted(path.relative_to(out) for path in out.rglob("*.png"))
    assert len(figures) >= 5  # the cells', Figure 1's and 2's, each game's tuning
    for figure in figures:
        assert (out / figure).read_bytes() == (results / figure).read_bytes(), figure
    assert missing_beside(results / "REPORT.md") == []
    assert sum(p.stat().st_size for p in (results / "v3" / "data").iterdir()) < 50 * 2**20
