"""The fenced python examples of docs/envs.md run as written (tiny suite)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "envs.md"
BLOCKS = re.findall(r"^```python\n(.*?)^```", DOC.read_text(), flags=re.S | re.M)


def test_docs_have_both_examples():
    assert len(BLOCKS) == 2
    assert "lax.scan" in BLOCKS[0] and "make_vec" in BLOCKS[1]


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_docs_example_runs(index, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    exec(compile(BLOCKS[index], f"{DOC}:block{index}", "exec"), {"__name__": "docs_example"})
    assert capsys.readouterr().out.strip(), "the example prints its results"
