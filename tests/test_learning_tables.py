"""docs/learning.md's tables are what `python -m dqn_transfer.cli.learning table` computes from the committed
data (results/learning/data/), so every figure there can be regenerated, and changes to the rules or the data
show up here."""

from __future__ import annotations

import re
from pathlib import Path

from dqn_transfer.experiments.learning import DIAGNOSES, EXAMPLES, PARITY, TABLES_FILE, tables
from dqn_transfer.experiments.raw_data import DATA_DIR

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "learning"


def test_the_docs_tables_are_the_committed_data_s():
    text = (ROOT / "docs" / "learning.md").read_text()
    block = re.search(r"<!-- tables: [^\n]*-->\n(.*?)<!-- end tables -->", text, re.S)
    assert block is not None
    computed = tables(RESULTS / DATA_DIR)
    assert block.group(1) == computed
    assert (RESULTS / TABLES_FILE).read_text() == computed


def test_every_sweep_has_its_committed_data():
    names = {e.name for e in EXAMPLES} | {PARITY} | set(DIAGNOSES)
    assert {p.stem for p in (RESULTS / DATA_DIR).glob("*.jsonl")} == names
