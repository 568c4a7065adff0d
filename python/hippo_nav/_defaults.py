"""The Rust cores' default parameters, the single source of every default the Python models show, and the
base class of every config section.

Each core serialises its `Params::default()` as JSON (`_core.default_params_json(section)`); the pydantic
models (`EngineConfig`, `MapParams`, `TemplateViewConfig`) take their field defaults from here, so a default
is written once, in Rust, and a test checks that the Python models agree with it.

`ConfigSection` is what every section of a config file (`hippo_nav.pipeline.PipelineConfig`) derives from:
unknown keys are errors, NaN and ±infinity are refused (JSON has no such numbers: they would reach the Rust
cores as `null`), and a number must be given as a number (`true` or `"12"` for a count is an error, not 1 or
12). Ranges are declared on each field (`Field(ge=…, le=…)`), so a bad value is refused in Python, with the
setting's path, before anything reaches Rust.
"""

from __future__ import annotations

import copy
import json
import types
from collections.abc import Callable
from functools import cache
from typing import Annotated, Any, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

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


def dotted(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested mapping with dotted keys, as the config is addressed on the command line and in messages:
    `{"views": {"novelty_threshold": 0.4}}` → `{"views.novelty_threshold": 0.4}`."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(dotted(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def merged(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """`top` laid over `base`, section by section: a key `top` sets wins, the rest of `base`'s section stays
    (a preset under a config file, a sweep's overrides over its base config). Both are left unchanged."""
    out = copy.deepcopy(base)
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merged(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def move_keys(
    data: dict[str, object], where: Callable[[str], tuple[str, ...] | None]
) -> tuple[dict[str, object], list[tuple[str, str]]]:
    """`data` with every key that `where` gives a new place (`(name,)` or `(section, name)`) moved there, and
    (old key, new dotted key) per key moved: how a section reads the spellings of older config files. A
    value already at the new place wins over the old spelling; a section that is not a mapping is left as it
    is, for validation to refuse."""
    out, moved = dict(data), []
    for key in list(out):
        path = where(key)
        if path is None:
            continue
        value = out.pop(key)
        if len(path) == 1:
            out.setdefault(path[0], value)
        else:
            section = out.get(path[0], {})
            if isinstance(section, dict):
                out[path[0]] = {path[1]: value, **section}
        moved.append((key, ".".join(path)))
    return out, moved


def _wrong_kind(annotation: Any, value: Any) -> str | None:
    """Why `value` is not of the kind `annotation` asks for (a bool, int or float, or a list, tuple or
    optional of them), or None. Only what pydantic's lax mode would silently convert is caught here:
    `true` for a number, a number for a switch, a string for either."""
    if value is None:
        return None
    origin = get_origin(annotation)
    if origin is Annotated:  # constraints (`Annotated[int, Field(ge=0)]`) do not change the kind
        return _wrong_kind(get_args(annotation)[0], value)
    if origin in (Union, types.UnionType):
        reasons = [_wrong_kind(a, value) for a in get_args(annotation) if a is not type(None)]
        return None if not reasons or None in reasons else reasons[0]
    if origin in (list, tuple) and isinstance(value, (list, tuple)):
        inner = [a for a in get_args(annotation) if a is not Ellipsis]
        for i, item in enumerate(value):
            kind = inner[min(i, len(inner) - 1)] if inner else Any
            reason = _wrong_kind(kind, item)
            if reason is not None:
                return f"item {i} ({item!r}) {reason}"
        return None
    if annotation is bool and not isinstance(value, bool):
        return f"must be true or false, not {type(value).__name__}"
    if annotation in (int, float) and isinstance(value, (bool, str, bytes)):
        what = "an integer" if annotation is int else "a number"
        return f"must be {what}, not {type(value).__name__}"
    return None


class ConfigSection(BaseModel):
    """Base of every config section (module doc): unknown keys, NaN/±inf and numbers given as text or
    booleans are errors naming the field."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _numbers_are_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        field = cls.model_fields.get(str(info.field_name))
        reason = None if field is None else _wrong_kind(field.annotation, value)
        if reason is not None:
            raise ValueError(reason)
        return value
