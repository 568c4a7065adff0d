"""Every Python snippet of the README and docs/ runs as pasted (in a fresh namespace and folder)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def snippets() -> list:
    found = []
    for page in PAGES:
        for k, match in enumerate(re.finditer(r"```python\n(.*?)```", page.read_text(), re.DOTALL)):
            found.append(pytest.param(match.group(1), id=f"{page.name}-{k}"))
    return found


@pytest.mark.parametrize("code", snippets())
def test_snippet_runs(code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "<snippet>", "exec"), {"__name__": "__snippet__"})  # noqa: S102 - running the docs is the test
