"""Every Python snippet of the README and docs/ runs as pasted (in a fresh namespace and folder).

Snippets that show a plug point register their part in a registry (`LOADERS`, `parts.*`); the registries
are put back after each snippet, so a page never changes what the other tests see."""

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


@pytest.fixture
def registries():
    from hippo_nav.datasets import LOADERS
    from hippo_nav.system import parts

    kept = [(registry, dict(registry)) for registry in (LOADERS, *parts.REGISTRIES.values())]
    yield
    for registry, before in kept:
        registry.clear()
        registry.update(before)


@pytest.mark.parametrize("code", snippets())
def test_snippet_runs(code, tmp_path, monkeypatch, registries):
    monkeypatch.chdir(tmp_path)
    # `dont_inherit`: the snippet runs as pasted, without this file's `from __future__ import annotations`.
    exec(compile(code, "<snippet>", "exec", dont_inherit=True), {"__name__": "__snippet__"})  # noqa: S102 - running the docs is the test
