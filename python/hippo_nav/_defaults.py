"""The Rust cores' default parameters, the single source of every default the Python models show.

Each core serialises its `Params::default()` as JSON (`_core.default_params_json(section)`); the pydantic
models (`EngineConfig`, `MapParams`, `TemplateViewConfig`) take their field defaults from here, so a default
is written once, in Rust, and a test checks that the Python models agree with it.
"""

from __future__ import annotations

import json
from functools import cache
from typing import Any

from hippo_nav import _core


@cache
def _section(section: str) -> dict[str, Any]:
    return json.loads(_core.default_params_json(section))


def rust_defaults(section: str) -> dict[str, Any]:
    """A copy of the defaults of `section` ("engine", "map" or "views") as plain JSON values."""
    return json.loads(json.dumps(_section(section)))


def rust_default(section: str, *path: str | int) -> Any:
    """One default, e.g. `rust_default("engine", "hd", "n_theta")`."""
    value: Any = _section(section)
    for key in path:
        value = value[key]
    return value
