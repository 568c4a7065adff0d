"""Every numeric setting of a config file is checked in Python before anything reaches Rust: NaN, ±infinity, a
number given as text or a boolean, a negative or absurdly large count are one-line errors naming the setting by
its path, its value and what it must be. What Python would let through, the Rust cores refuse naming the same
path (never a line and column of JSON the user did not write). The grid modules can be changed one field at a
time in the forms docs/pipeline.md shows."""

from __future__ import annotations

import json
import math
import re
import types
from collections.abc import Iterator
from typing import Any, Union, get_args, get_origin

import annotated_types
import pytest
from conftest import PROJECT_ROOT
from hippo_nav import HippoNavError, _core
from hippo_nav.engine import MODULE_NAMES, EngineConfig, GridConfig, SpatialMemory
from hippo_nav.pipeline import PipelineConfig, config_from_dict
from hippo_nav.plugs import PartSections
from pydantic import BaseModel
from pydantic.fields import FieldInfo

NUMBERS = (int, float)


def _plain(annotation: Any) -> Any:
    """`int | None` → int; anything else as it is."""
    if get_origin(annotation) in (Union, types.UnionType):
        inner = [a for a in get_args(annotation) if a is not type(None)]
        return inner[0] if len(inner) == 1 else annotation
    return annotation


def _leaves(model: type[BaseModel], path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], str, Any]]:
    """(path to write in a config, path an error names, type) of every bool, int and float setting, the grid
    modules' fields once per module (by name in the config, by index in the error)."""
    for name, field in model.model_fields.items():
        key = field.alias or name
        kind = _plain(field.annotation)
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            yield from _leaves(kind, (*path, key))
        elif get_origin(kind) is list and get_args(kind) == (GridConfig,):
            for index, module in enumerate(MODULE_NAMES):
                for (sub_key,), _, sub_kind in _leaves(GridConfig):
                    yield (
                        (*path, key, module, sub_key),
                        f"{'.'.join((*path, key))}[{index}].{sub_key}",
                        sub_kind,
                    )
        elif kind in (bool, int, float):
            yield (*path, key), ".".join((*path, key)), kind
    # The sections of registered parts (derived from the registries: `vo`, `views`, `closure.proximity`, …).
    if issubclass(model, PartSections):
        for name, section in model.part_sections().items():
            yield from _leaves(section, (*path, name))


LEAVES = list(_leaves(PipelineConfig))
FLOATS = [(w, n) for w, n, kind in LEAVES if kind is float]
INTS = [(w, n) for w, n, kind in LEAVES if kind is int]
BOOLS = [(w, n) for w, n, kind in LEAVES if kind is bool]


def _nested(path: tuple[str, ...], value: Any) -> dict[str, Any]:
    for key in reversed(path):
        value = {key: value}
    return value


def _error(data: dict[str, Any]) -> str:
    with pytest.raises(HippoNavError) as caught:
        config_from_dict(data, "c.json")
    message = str(caught.value)
    assert len(message.splitlines()) == 1, message
    return message


def test_the_walk_finds_every_section():
    names = {n for _, n, _ in LEAVES}
    assert {
        "engine.hd.n_theta",
        "engine.grid[2].lambda",
        "views.novelty_threshold",
        "vo.max_features",
    } <= names
    assert {"map.loop_gate_m", "closure.max_distance_m", "view_words.top_k", "seed"} <= names
    assert {
        "closure.proximity.min_inliers",
        "closure.confirm.agreement_m",
        "closure.birdseye.min_points",
    } <= names
    assert len(FLOATS) > 80 and len(INTS) > 40


@pytest.mark.parametrize(("where", "name"), FLOATS, ids=[n for _, n in FLOATS])
def test_every_float_setting_refuses_nan_and_infinity(where, name):
    for value in (math.nan, math.inf, -math.inf):
        message = _error(_nested(where, value))
        assert f"c.json: invalid config: {name}: " in message and "finite number" in message, message


@pytest.mark.parametrize(("where", "name"), INTS, ids=[n for _, n in INTS])
def test_every_count_refuses_wrong_types_negative_and_absurd_values(where, name):
    for value, phrase in (
        (True, "must be an integer, not bool"),
        ("12", "must be an integer, not str"),
        (2.5, "fractional part"),
        (-1, "greater than or equal to"),
        (10**12, "less than or equal to"),
    ):
        message = _error(_nested(where, value))
        assert f"{name}: " in message and phrase in message, (value, message)


@pytest.mark.parametrize(("where", "name"), BOOLS, ids=[n for _, n in BOOLS])
def test_every_switch_takes_true_or_false_only(where, name):
    for value in (1, "yes", 0.0):
        assert f"{name}: must be true or false" in _error(_nested(where, value))


def _bounds(field: FieldInfo) -> set[type]:
    return {type(m) for m in field.metadata}


def _models(model: type[BaseModel]) -> Iterator[type[BaseModel]]:
    yield model
    for field in model.model_fields.values():
        kind = _plain(field.annotation)
        inner = get_args(kind)[0] if get_origin(kind) is list else kind
        if isinstance(inner, type) and issubclass(inner, BaseModel):
            yield from _models(inner)


def test_every_count_has_a_lower_and_an_upper_bound():
    """A new count added without bounds fails here: 10¹² units or iterations must never reach Rust or OpenCV."""
    for model in set(_models(PipelineConfig)):
        for name, field in model.model_fields.items():
            if _plain(field.annotation) is int:
                bounds = _bounds(field)
                assert bounds & {annotated_types.Ge, annotated_types.Gt}, (
                    f"{model.__name__}.{name}: no lower bound"
                )
                assert bounds & {annotated_types.Le, annotated_types.Lt}, (
                    f"{model.__name__}.{name}: no upper bound"
                )


def test_the_reported_example_names_setting_value_and_bound():
    message = _error({"engine": {"hd": {"n_theta": -3}}})
    assert "engine.hd.n_theta: Input should be greater than or equal to 4 (got -3)" in message
    assert "line 1 column" not in message
    assert "views.novelty_threshold: Input should be a finite number (got nan)" in _error(
        {"views": {"novelty_threshold": math.nan}}
    )


@pytest.mark.parametrize(
    ("config", "phrase"),
    [
        ({"engine": {"hd": {"n_theta": 60000, "n_nu": 1000}}}, "engine.hd: n_theta · n_nu = 60000 · 1000"),
        ({"engine": {"grid": {"n_theta": 1024, "n_nu": 64}}}, "engine.grid[0]: n_theta² · n_nu²"),
        ({"views": {"width_px": 4096, "height_px": 4096}}, "views: width_px · height_px = 4096 · 4096"),
        ({"engine": {"max_substep_s": 0.9}}, "max_substep_s = 0.9 s is longer than 5·tau_s"),
        ({"views": {"crop_rows_frac": [0.7, 0.1]}}, "crop_rows_frac = (0.7, 0.1): need 0 ≤ top < bottom ≤ 1"),
        ({"views": {"crop_rows_frac": [math.nan, 0.7]}}, "views.crop_rows_frac[0]: Input should be a finite"),
        ({"views": {"max_shift_px": 40}}, "max_shift_px = 40 must be under half the template width"),
        ({"views": {"patch_size_px": 4}}, "patch_size_px = 4 must be odd"),
        ({"output": {"state_frames": [True]}}, "output.state_frames: item 0 (True) must be an integer"),
        ({"engine": {"lesioned": [1, 0, 0]}}, "engine.lesioned: item 0 (1) must be true or false"),
    ],
)
def test_settings_that_only_fail_together_are_named(config, phrase):
    assert phrase in _error(config)


# --- the Rust side: whatever Python would let through is refused there too, by its path ------------------------
def _engine_json(change) -> str:
    data = json.loads(EngineConfig().to_json())
    change(data)
    return json.dumps(data)


def _engine_error(change) -> str:
    with pytest.raises(HippoNavError) as caught:
        _core._SpatialMemory(_engine_json(change))
    return str(caught.value)


def test_rust_config_errors_name_the_field_path_not_a_json_column():
    for change, phrase in (
        (
            lambda d: d["hd"].update(n_theta=-3),
            "invalid engine config: engine.hd.n_theta: invalid value: integer `-3`",
        ),
        (lambda d: d["hd"].update(j1=None), "engine.hd.j1: invalid type: null, expected a finite number"),
        (lambda d: d["grid"][1].update(k="two"), 'engine.grid[1].k: invalid type: string "two"'),
        (
            lambda d: d["place"].update(extra=1),
            "engine.place.extra: unknown field `extra`, expected one of `n_theta`",
        ),
        (lambda d: d.pop("settle_s"), "engine: missing field `settle_s`"),
        (lambda d: d["hd"].update(n_theta=3), "engine.hd.n_theta = 3: must be between 4 and 65536"),
        (lambda d: d["grid"][2].update(k=3), "engine.grid[2].n_theta = 64: must be a multiple of k = 3"),
        (lambda d: d["grid"][1].update(n_theta=32), "engine.grid[1].n_theta = 32: must equal place.n_theta"),
        (lambda d: d.update(settle_s=1e9), "engine.settle_s = 1000000000: must lie in [0, 10]"),
    ):
        message = _engine_error(change)
        assert phrase in message and "line 1" not in message, message
    with pytest.raises(HippoNavError, match=r"views\.width_px: invalid type: string \"wide\""):
        _core._ViewCells('{"width_px": "wide"}')


def _beyond(constraint: Any, kind: type) -> Any:
    """A value just outside a field's bound."""
    if isinstance(constraint, annotated_types.Ge):
        return constraint.ge - 1 if kind is int else constraint.ge - max(abs(constraint.ge) * 0.5, 1e-6)
    if isinstance(constraint, annotated_types.Le):
        return constraint.le + 1 if kind is int else constraint.le + max(abs(constraint.le), 1.0)
    if isinstance(constraint, annotated_types.Gt):
        return constraint.gt
    if isinstance(constraint, annotated_types.Lt):
        return constraint.lt
    return None


def _engine_bounds() -> Iterator[tuple[str, tuple[Any, ...], Any]]:
    def walk(model: type[BaseModel], path: tuple[Any, ...]):
        for name, field in model.model_fields.items():
            key, kind = field.alias or name, _plain(field.annotation)
            if isinstance(kind, type) and issubclass(kind, BaseModel):
                yield from walk(kind, (*path, key))
            elif get_origin(kind) is list and get_args(kind) == (GridConfig,):
                for index in range(len(MODULE_NAMES)):
                    yield from walk(GridConfig, (*path, key, index))
            elif kind in NUMBERS:
                for constraint in field.metadata:
                    value = _beyond(constraint, kind)
                    if value is not None:
                        yield kind, (*path, key), value

    yield from walk(EngineConfig, ())


ENGINE_BOUNDS = list(_engine_bounds())


def _dotted(path: tuple[Any, ...]) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


@pytest.mark.parametrize(
    ("kind", "path", "value"), ENGINE_BOUNDS, ids=[f"{_dotted(p)}={v}" for _, p, v in ENGINE_BOUNDS]
)
def test_python_and_rust_refuse_the_same_engine_values(kind, path, value):
    """Each engine bound the Python model declares, the Rust engine enforces too (naming the same path): the
    two cannot drift apart, and `_core` used directly is as safe as the config file."""

    def change(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    message = _engine_error(change)
    assert f"engine.{_dotted(path)}" in message, message


# --- grid modules one field at a time (docs/pipeline.md) ---------------------------------------------------------
def _json_examples(page: str, heading: str) -> list[dict[str, Any]]:
    text = (PROJECT_ROOT / "docs" / page).read_text()
    section = text.split(heading, 1)[1].split("\n#", 1)[0]
    return [json.loads(block) for block in re.findall(r"```json\n(.*?)```", section, re.DOTALL)]


def test_the_documented_grid_forms_load_and_build_an_engine():
    examples = _json_examples("pipeline.md", "### Grid modules")
    assert len(examples) >= 4
    for example in examples:
        config = config_from_dict(example, "docs/pipeline.md")
        SpatialMemory(config.engine_config())


ALTERNATIVES = {
    "k": 8,
    "n_nu": 7,
    "nu_max": 0.05,
    "lambda": 11.0,
    "j0": -5000.0,
    "jk": 2500.0,
    "input_amp": 0.8,
    "input_tuning": 0.4,
    "input_sigma": 0.02,
    "pin_gain": 0.2,
}


_NAMES = {field.alias or name: name for name, field in GridConfig.model_fields.items()}


@pytest.mark.parametrize("field", ALTERNATIVES)
@pytest.mark.parametrize("form", ["list", "by name"])
def test_one_field_of_one_module_changes_that_module_only(field, form):
    default = EngineConfig()
    for index, module in enumerate(MODULE_NAMES):
        grid: Any = {module: {field: ALTERNATIVES[field]}}
        if form == "list":
            grid = [{field: ALTERNATIVES[field]} if i == index else {} for i in range(len(MODULE_NAMES))]
        engine = config_from_dict({"engine": {"grid": grid}}).engine
        for i, (got, was) in enumerate(zip(engine.grid, default.grid)):
            changed = was.model_copy(update={_NAMES[field]: ALTERNATIVES[field]})
            assert got == (changed if i == index else was), (module, i)


@pytest.mark.parametrize(
    "config",
    [
        {"grid": {"n_theta": 32}},
        {"grid": {"all": {"n_theta": 32}}},
        {"grid": [{"n_theta": 32}, {"n_theta": 32}, {"n_theta": 32}]},
        {"place": {"n_theta": 32}},
        {"grid": {"n_theta": 32}, "place": {"n_theta": 32}},
    ],
)
def test_the_torus_size_is_one_setting_given_on_either_side(config):
    engine = config_from_dict({"engine": config}).engine
    assert [g.n_theta for g in engine.grid] == [32] * len(MODULE_NAMES) and engine.place.n_theta == 32
    assert [g.k for g in engine.grid] == [g.k for g in EngineConfig().grid]
    assert SpatialMemory(engine).place_activity().shape == (32, 32)


@pytest.mark.parametrize(
    ("grid", "phrase"),
    [
        ({"dorsal": {"n_theta": 32}}, "grid[2] (dorsal).n_theta = 32 differs from place.n_theta = 64"),
        ([{}, {"n_theta": 48}, {}], "grid[1] (intermediate).n_theta = 48 differs from place.n_theta = 64"),
        ([{"n_theta": 32}], "a list gives all 3 modules (ventral, intermediate, dorsal), got 1"),
        (
            {"4": {"nu_max": 0.1}},
            "'4' is neither a module (ventral, intermediate, dorsal or 'all') nor a grid field",
        ),
        ({"dorsal": 0.1}, "grid.dorsal must be an object of grid fields"),
        ({"dorsal": {"k": 3}}, "engine.grid[2]: n_theta = 64 must be a multiple of k = 3"),
    ],
)
def test_a_wrong_grid_form_says_what_to_write(grid, phrase):
    message = _error({"engine": {"grid": grid}})
    assert phrase in message, message
