"""The README's "Use it from Python" snippet runs as written (extracted from README.md, so the two cannot drift)."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_snippet(heading: str) -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, f"README.md '{heading}': expected one python block, found {len(blocks)}"
    return blocks[0]


def test_use_it_from_python_snippet_runs_as_written(capsys):
    code = _python_snippet("Use it from Python")
    namespace: dict = {}
    exec(compile(code, f"{README}:Use it from Python", "exec"), namespace)  # noqa: S102 - our own README
    result = namespace["result"]
    assert len(result.rows) >= 1
    row = result.rows[0]
    assert row["policy"] == "expert"
    assert str(row) in capsys.readouterr().out


def test_load_policy_takes_the_cli_names():
    from drivee2e_jax.policy import load_policy

    assert load_policy("expert").name == "expert"
    assert load_policy("stop:name=halt").name == "halt"
