"""The config documented where a user looks for it: every section of `PipelineConfig` has a row in the
table of docs/pipeline.md, and every field of the sections documented there (and of the map's, in
docs/map.md) is named; a field added without its documentation fails here."""

from __future__ import annotations

import re

from conftest import PROJECT_ROOT
from hippo_nav.closure import ClosureConfig
from hippo_nav.map import MapParams
from hippo_nav.pipeline import PipelineConfig

# Sections whose fields are documented on their own pages (engine: model.md, vo: vo.md, views: spec.md §7,
# map: map.md, checked below); the table names each and points there.
ELSEWHERE = {"engine", "vo", "views", "map"}


def _table_rows(page: str) -> dict[str, str]:
    text = (PROJECT_ROOT / "docs" / page).read_text()
    return {m.group(1): m.group(0) for m in re.finditer(r"^\| `([\w.]+)` \|.*$", text, re.MULTILINE)}


def _sections() -> dict[str, object]:
    """Every section of the config: its fields, the registered parts' sections (derived from the registries)
    and the closure proposers' nested ones."""
    sections: dict[str, object] = {k: f.annotation for k, f in PipelineConfig.model_fields.items()}
    sections.update(PipelineConfig.part_sections())
    sections.update({f"closure.{k}": m for k, m in ClosureConfig.part_sections().items()})
    return sections


def test_every_config_section_and_field_is_in_the_pipeline_table():
    rows = _table_rows("pipeline.md")
    for section, model in _sections().items():
        assert section in rows, f"docs/pipeline.md: no row for the `{section}` section"
        fields = getattr(model, "model_fields", None)
        if section in ELSEWHERE or fields is None:
            continue
        missing = [name for name in fields if f"`{name}`" not in rows[section]]
        assert not missing, f"docs/pipeline.md, row `{section}`: fields {missing} are not named"


def test_every_map_parameter_is_in_docs_map():
    text = (PROJECT_ROOT / "docs" / "map.md").read_text()
    missing = [name for name in MapParams.model_fields if f"`{name}`" not in text]
    assert not missing, f"docs/map.md does not name {missing}"
