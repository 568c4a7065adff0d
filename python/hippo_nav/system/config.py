"""Typed configuration of a pipeline run: small pydantic sections, one file, defaults defined once.

A config file is JSON (`.json`) holding any subset of the sections below; every field it leaves out
takes its documented default (the engine, map and view-cell defaults come from the Rust cores, so they
exist in one place only). `load_config(path)` reads and validates a file, `write_config(config, path)`
writes the fully resolved config, which every run puts into its results folder (`config.json`) so a
run can be repeated from its own output.

Sections:
- `preset`: the named settings laid under the file's own (`hippo_nav.system.presets`: `default`, `paper`, the
  system as the paper describes it); whatever the file sets itself wins.
- `seed`: the one seed of a run: where the networks' bumps start (heading code and grid phases), and
  OpenCV's RNG. The odometry does not depend on it (OpenCV's RANSAC uses its own fixed seed).
- `overlap_front_end`: load frames and measure the odometry ahead, on worker threads (same results).
- `parts`: which implementation fills each plug point (`hippo_nav.system.parts`).
- `engine`: the spatial-memory network (`hippo_nav.engine.EngineConfig`).
- `lesions`: "MEC inactivation" of each grid module — the one place lesions are set for a run (the
  engine's `lesioned` list is derived from it).
- one section per registered odometry and view descriptor, derived from their registries
  (`hippo_nav.plugs.Part.section`): `vo`, the stereo VO (`hippo_nav.vo.VoParams`); `views`, the template
  view cells (`hippo_nav.view_cells.TemplateViewConfig`; `field_of_view_rad` defaults to the camera's);
  `view_words`, the word view cells (`hippo_nav.view_cells.WordViewConfig`).
- `view_search`: which stored views a frame is compared with (`ViewSearchConfig`).
- `injection`: how familiar views pull the network back (docs/spec.md §7, see `InjectionConfig`).
- `map`: experience-map creation, loop-closure mode and gates, online correction (`hippo_nav.map.MapParams`).
- `closure`: geometric loop closure: the keyframe store and its PnP measurements, and one nested section per
  registered proposer (`closure.view_cell`, `closure.proximity`, …; `hippo_nav.closure.ClosureConfig`).
- `correction`: the final correction run after the last frame (`CorrectionConfig`).
- `limits`: the motion the engine is given at most; larger VO outputs are clamped (`MotionLimits`).
- `output`: what is written besides trajectories and metrics (`OutputConfig`).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from hippo_nav._core import HippoNavError
from hippo_nav._defaults import ConfigSection
from hippo_nav.closure import DEFAULT_PROPOSERS, PROPOSERS, ClosureConfig
from hippo_nav.closure.config import migrate_flat_closure
from hippo_nav.engine import EngineConfig
from hippo_nav.io.atomic import write_text
from hippo_nav.io.errors import MAX_SETTINGS_FILE_BYTES, read_text
from hippo_nav.map import ClosureMode, MapParams
from hippo_nav.plugs import Part, PartSections
from hippo_nav.system.presets import PRESETS, under_preset
from hippo_nav.view_cells import DESCRIPTORS
from hippo_nav.vo import ODOMETRIES

log = logging.getLogger("hippo_nav.pipeline")

# The registry of each field of the `parts` section.
_REGISTRIES: dict[str, Mapping[str, Part[Callable[..., object]]]] = {
    "odometry": ODOMETRIES,
    "view_cells": DESCRIPTORS,
    "closure": PROPOSERS,
}

# Counts of frames, cells or iterations: generous, but an int a C library still takes (and no typo of a few
# extra digits that would run for days).
_MAX_COUNT = 1_000_000

# How deep a config's sections nest at most: the deepest real setting is 3 levels down (closure.<proposer>.x);
# a deeper structure is a mistake, and refusing it here keeps every recursive step after (validation, the
# messages) far from Python's recursion limit.
_MAX_DEPTH = 32
# Characters of a bad value quoted in a message: a pasted megabyte stays one readable line.
_SHOWN_CHARS = 60


class _Section(ConfigSection):
    pass


class LesionConfig(_Section):
    """Switch grid modules off ("MEC inactivation"); a lesioned module leaves the Bayesian fusion."""

    ventral: bool = Field(False, description="the coarsest module (k = 1, one bump)")
    intermediate: bool = Field(False, description="the middle module (k = 2, four bumps)")
    dorsal: bool = Field(False, description="the finest module (k = 4, sixteen bumps)")


class InjectionConfig(_Section):
    """Familiar-view injection (docs/spec.md §7).

    When a new view cell is created, the network's `view_patterns()` (HD θ-profile, the three layer-II
    patterns) are stored with it. When a familiar cell is matched, its stored patterns are injected as
    `I_view` with strength `s = initial_strength · decay_per_frame^a`, where `a` is the number of frames
    the same cell has been active in a row (0 on the frame it becomes active). Injection stops once
    `s < min_strength`, so a view that stays put (a parked car, a red light) stops pulling the network.
    A cell that becomes active again within `revisit_gap_frames` of its last activity (the agent is still
    on the passage where it was stored) injects nothing: its older state would drag path integration
    backwards and make the map close onto vertices a few metres behind. With `shift_heading` the stored
    HD profile is rotated by the match's relative heading first (the camera may face a little differently
    than when the view was stored).

    `placement` says where the recalled state is put. `as_stored` (the paper's): exactly as it was stored,
    i.e. the agent is taken to be where the view was first seen, the heading turned by the view's relative
    heading (`shift_heading`). `measured` (default): recalled only on a frame whose loop closure was
    measured (stereo, in the map's geometric mode), moved by the measured pose between the agent and where
    the view was stored — the heading turned by the measured yaw, the grid bumps shifted by
    `2π·d/torus_period_m` for the measured displacement d (docs/spec.md §3) — so a view recognised from
    metres away recalls the state of the place the agent is at. Word cells recognise a place 5–10 m before
    it (docs/views.md): recalled as stored, the place code would be pulled that far (demo loop: neural ATE
    2.7 m against 0.34 m measured). In the RatSLAM closure mode nothing is measured, so `as_stored` applies
    unless `measured` is asked for explicitly, which is then an error.
    """

    enabled: bool = True
    initial_strength: float = Field(
        1.0, ge=0.0, le=1e3, description="s0, injected on the first familiar frame"
    )
    decay_per_frame: float = Field(0.7, gt=0.0, le=1.0, description="factor per frame the view stays active")
    min_strength: float = Field(0.05, ge=0.0, description="below this strength nothing is injected")
    revisit_gap_frames: int = Field(
        20,
        ge=0,
        le=_MAX_COUNT,
        description="a cell injects only when it was last active more than this many frames ago",
    )
    shift_heading: bool = Field(True, description="rotate the stored HD profile by the relative heading")
    placement: Literal["as_stored", "measured"] = Field(
        "measured", description="where the recalled state is put (see above)"
    )
    max_placement_m: float = Field(
        15.0,
        gt=0.0,
        description="`measured`: a recall farther than this from where the view was stored is skipped",
    )


class ViewSearchConfig(_Section):
    """Which stored views a frame is compared with.

    The paper compares every template, so the cost of a frame grows with the run (27 ms at 3 500 cells).
    With `near_only` a frame is compared with the cells first seen near where the odometry puts it in
    the map — within the map's loop gate (`ExperienceMap.loop_gate`) plus `radius_margin_m`, at most
    `max_radius_m` — and with the `recent_cells` newest cells: the cost stays flat, and a view of a place
    the map says is far away (a look-alike) can neither inject nor close a loop.

    The cells made within the last `passage_m` of travel are the passage the agent is on; the descriptor
    is told which they are (`ViewDescriptor.observe(…, recent=…)`): the word view cells keep such a cell
    active only while the view stays close to it, and look for a revisit among the older ones first (the
    template cells treat every cell alike)."""

    near_only: bool = True
    radius_margin_m: float = Field(20.0, ge=0.0)
    max_radius_m: float = Field(200.0, gt=0.0)
    recent_cells: int = Field(30, ge=0, le=_MAX_COUNT)
    passage_m: float = Field(
        50.0, ge=0.0, description="cells made within this much travel belong to the current passage"
    )


class PartsConfig(_Section):
    """Which implementation fills each plug point: a name in its package's registry (`vo.ODOMETRIES`,
    `view_cells.DESCRIPTORS`, `closure.PROPOSERS`; docs/architecture.md). Each part takes its parameters from
    its own section (the registry entry's `section`: `vo`; `views` for the template view cells,
    `view_words` for the word view cells; `closure.<proposer>`)."""

    odometry: str = Field("stereo", description="the odometry (`vo.ODOMETRIES`)")
    view_cells: str = Field("words", description="the view descriptor (`view_cells.DESCRIPTORS`)")
    closure: list[str] = Field(
        default_factory=lambda: list(DEFAULT_PROPOSERS),
        description="the loop-closure proposers in the map's geometric mode, asked in this order "
        '(`closure.PROPOSERS`; add "birdseye" for streets driven the other way)',
    )

    @field_validator("odometry", "view_cells")
    @classmethod
    def _registered(cls, name: str, info: ValidationInfo) -> str:
        _check_registered(str(info.field_name), [name])
        return name

    @field_validator("closure")
    @classmethod
    def _proposers_registered(cls, names: list[str]) -> list[str]:
        _check_registered("closure", names)
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(
                f"{', '.join(map(repr, twice))} listed twice; each proposer is asked once a frame"
            )
        return names


def _check_registered(plug: str, names: list[str]) -> None:
    registry = _REGISTRIES[plug]
    for name in names:
        if name not in registry:
            raise ValueError(f"unknown {name!r}; choose from {', '.join(sorted(registry))}")


class CorrectionConfig(_Section):
    """The map correction run once after the last frame (the online passes are in `map`)."""

    method: Literal["least_squares", "relaxation", "none"] = "least_squares"
    robust_loss: Literal["dcs", "cauchy"] | None = Field(
        None,
        description="robust loss on loop links (least squares only): wrong closures lose weight. Off by "
        "default: a single true closure after a long drift has a large residual and would be rejected.",
    )
    robust_scale_chi2: float = Field(1.0, gt=0.0)
    max_iterations: int = Field(100, ge=1, le=100_000)
    relaxation_passes: int = Field(200, ge=1, le=_MAX_COUNT)
    relaxation_gain: float = Field(0.5, gt=0.0, lt=1.0)


class MotionLimits(_Section):
    """What the engine is given at most. The VO can report absurd motion on a bad frame; the engine
    rejects velocities beyond its velocity axes, so the pipeline clamps here and flags the frame."""

    max_speed_m_s: float = Field(35.0, gt=0.0)
    max_yaw_rate_rad_s: float = Field(3.0, gt=0.0)
    max_gap_s: float = Field(
        1.0,
        gt=0.0,
        description="a longer time between sequence frames is a gap (times the stride for a run of every "
        "n-th frame): flagged, and the networks integrate the odometry's step over this time at most instead "
        "of the whole gap",
    )


class OutputConfig(_Section):
    figures: bool = Field(True, description="write the figures (cognitive map, neural state, rate maps)")
    # Each snapshot is the whole network state; a frame number past 10⁹ or thousands of them is a typo.
    state_frames: Annotated[list[Annotated[int, Field(ge=0, le=10**9)]], Field(max_length=1000)] | None = (
        Field(
            None,
            description="frames (0-based positions in the run) of the neural state panels; None: first, middle, last",
        )
    )
    rate_map_bin_m: float = Field(
        4.0,
        ge=0.1,
        le=1000.0,
        description="spatial bin of the firing-rate maps (0.1–1000 m: finer bins would need gigabytes over a city)",
    )
    save_map: bool = Field(
        True, description="write map.bin, map.g2o and memory/ (what `--map` starts a later run inside)"
    )
    recording: bool = Field(
        True,
        description="write recording.npz and module_phase.npz (the networks' sampled units and decoded "
        "phases per frame, for `hippo-nav figures --run`)",
    )


def _odometries() -> Mapping[str, Part[Callable[..., object]]]:
    return ODOMETRIES


def _descriptors() -> Mapping[str, Part[Callable[..., object]]]:
    return DESCRIPTORS


class PipelineConfig(PartSections):
    """Everything a run needs besides its input. The sections of the registered odometries and view
    descriptors (`vo`, `views`, `view_words`, and any registered since) are derived from their registries."""

    registries: ClassVar[tuple[Any, ...]] = (_odometries, _descriptors)

    preset: str = Field(
        "default",
        description="the named settings laid under this config (`hippo_nav.system.presets`: default, paper); "
        "the config's own settings win",
    )
    seed: int = Field(0, ge=0, le=2**31 - 1, description="one seed for every random choice of the run")
    overlap_front_end: bool = Field(
        True,
        description="load frames and run the odometry up to three frames ahead of the networks and the "
        "map, each on a worker thread (same results; they overlap on two cores)",
    )
    parts: PartsConfig = Field(default_factory=PartsConfig)
    engine: EngineConfig = Field(default_factory=EngineConfig)
    lesions: LesionConfig = Field(default_factory=LesionConfig)
    view_search: ViewSearchConfig = Field(default_factory=ViewSearchConfig)
    injection: InjectionConfig = Field(default_factory=InjectionConfig)
    map: MapParams = Field(default_factory=MapParams)
    closure: ClosureConfig = Field(default_factory=ClosureConfig)
    correction: CorrectionConfig = Field(default_factory=CorrectionConfig)
    limits: MotionLimits = Field(default_factory=MotionLimits)
    output: OutputConfig = Field(default_factory=OutputConfig)

    @field_validator("preset")
    @classmethod
    def _known_preset(cls, name: str) -> str:
        if name not in PRESETS:
            raise ValueError(f"unknown {name!r}; choose from {', '.join(PRESETS)}")
        return name

    @model_validator(mode="before")
    @classmethod
    def _read_flat_closure_keys(cls, data: object) -> object:
        """The preset's settings laid under the config's own (`hippo_nav.system.presets`; an unknown name is
        left to the `preset` field's error). Configs written before the closure proposers had sections of
        their own (module doc of `hippo_nav.closure.config`) are read as they meant, with a warning naming each
        key's new place."""
        if not isinstance(data, dict):
            return data
        if isinstance(data.get("preset"), str) and data["preset"] in PRESETS:
            data = under_preset(data)
        parts, closure = data.get("parts", {}), data.get("closure", {})
        if not isinstance(parts, dict) or not isinstance(closure, dict):
            return data
        proposers = parts.get("closure", list(DEFAULT_PROPOSERS))
        if proposers == "view_cell_pnp":  # the one proposer of then, which did all of these (and no more)
            proposers = ["relocalisation", "view_cell", "proximity"]
        if not isinstance(proposers, list):
            return data
        closure, proposers, moved = migrate_flat_closure(closure, proposers)
        if not moved and parts.get("closure") == proposers:
            return data
        for line in moved:
            log.warning("config: %s (the old spelling still reads; write the new one)", line)
        return {**data, "parts": {**parts, "closure": proposers}, "closure": closure}

    @model_validator(mode="after")
    def _one_source_per_setting(self) -> PipelineConfig:
        # One seed for the whole run: a section's own seed field (the VO's) follows it.
        for name in self.part_sections():
            section = self.section(name)
            seed = getattr(section, "seed", None) if "seed" in type(section).model_fields else None
            if seed is None:
                continue
            if "seed" in section.model_fields_set and seed != self.seed:
                raise ValueError(
                    f"{name}.seed ({seed}) differs from seed ({self.seed}); set the seed once, at the top level"
                )
            if seed != self.seed:
                assert self.__pydantic_extra__ is not None
                self.__pydantic_extra__[name] = section.model_copy(update={"seed": self.seed})
        # A measured placement needs measured closures: the RatSLAM closure mode has none.
        if self.map.closure != ClosureMode.GEOMETRIC and self.injection.placement == "measured":
            if "placement" in self.injection.model_fields_set:
                raise ValueError(
                    "injection.placement = measured needs measured loop closures (map.closure = Geometric); "
                    "with the RatSLAM closure use as_stored"
                )
            injection = self.injection.model_copy(update={"placement": "as_stored"})
            object.__setattr__(self, "injection", injection)
        # Lesions live in one place: the `lesions` section (or --lesion).
        if any(self.engine.lesioned):
            raise ValueError(
                "engine.lesioned: set lesions in the `lesions` section (or with --lesion), e.g. "
                '{"lesions": {"dorsal": true}}'
            )
        return self

    def engine_config(self) -> EngineConfig:
        """The engine config with the `lesions` section applied."""
        return self.engine.with_lesions(self.lesions.ventral, self.lesions.intermediate, self.lesions.dorsal)

    def with_lesions(self, *names: str) -> PipelineConfig:
        """A copy with the named modules ("ventral", "intermediate", "dorsal") lesioned."""
        unknown = set(names) - set(LesionConfig.model_fields)
        if unknown:
            raise HippoNavError(
                f"unknown lesion {sorted(unknown)}; choose from ventral, intermediate, dorsal"
            )
        lesions = self.lesions.model_copy(update={name: True for name in names})
        return self.model_copy(update={"lesions": lesions})


def describe_validation_error(err: ValidationError) -> str:
    """A pydantic error as one line naming every bad field and its value: `a.b: message (got X)`."""
    return _describe(err)


def _describe(err: ValidationError) -> str:
    parts = []
    for e in err.errors():
        where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in e["loc"]).lstrip(".")
        where = where or "(top level)"
        message = e["msg"].replace("\n", " ")
        if e["type"] == "value_error":
            message = message.removeprefix("Value error, ")
        given = e.get("input")
        shown = "" if isinstance(given, (dict, list)) or given is None else f" (got {_shown(given)})"
        parts.append(f"{_shown_text(where)}: {_shown_text(message, 4 * _SHOWN_CHARS)}{shown}")
    return "; ".join(parts)


def _shown_text(text: str, limit: int = _SHOWN_CHARS) -> str:
    """`text` cut to `limit` characters, a lone surrogate (JSON's "\\ud800") escaped: the message must encode
    as UTF-8 wherever it is printed or written, and control characters escaped: the message stays one line."""
    text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    # A newline or other control character in a key or value (found by Hypothesis) must not break the line.
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def _shown(value: object) -> str:
    """`repr(value)` cut to `_SHOWN_CHARS` (the repr of an int of 5 000 digits is refused by Python itself)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**_SHOWN_CHARS:
        return f"an integer of about {value.bit_length() * 0.30103:.0f} digits"
    return _shown_text(repr(value))


def _check_structure(data: object, source: str) -> None:
    """Refuse what no config holds and the validators after cannot take: nesting deeper than `_MAX_DEPTH`
    and keys that are not strings (a YAML or TOML sweep file can give `1:`); the error names the place."""
    stack: list[tuple[object, str, int]] = [(data, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if depth > _MAX_DEPTH:
            raise HippoNavError(
                f"{source}: {_shown_text(where) or '(top level)'}: nested more than {_MAX_DEPTH} levels deep; a config holds "
                "sections of settings, a few levels at most"
            )
        if isinstance(value, dict):
            for key, item in value.items():
                if not isinstance(key, str):
                    raise HippoNavError(
                        f"{source}: {_shown_text(where) or '(top level)'}: key {_shown(key)} is a {type(key).__name__}; "
                        "setting names are text"
                    )
                stack.append((item, f"{where}.{key}".lstrip("."), depth + 1))
        elif isinstance(value, (list, tuple)):
            stack.extend((item, f"{where}[{i}]", depth + 1) for i, item in enumerate(value))


def _refuse_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """`json.loads`'s `object_pairs_hook`: a key given twice in one object is an error (JSON would keep the
    last silently, so a setting edited in one place would be overridden by a forgotten copy below it)."""
    data: dict[str, Any] = {}
    for key, value in pairs:
        if key in data:
            raise _DuplicateKey(key)
        data[key] = value
    return data


class _DuplicateKey(Exception):
    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def config_from_dict(data: dict[str, Any], source: str = "config") -> PipelineConfig:
    """Validate a dict into a `PipelineConfig`; errors name every bad field."""
    if not isinstance(data, dict):
        raise HippoNavError(f"{source}: a config holds one mapping of sections, not a {type(data).__name__}")
    _check_structure(data, source)
    try:
        return PipelineConfig.model_validate(data)
    except ValidationError as err:
        raise HippoNavError(f"{source}: invalid config: {_describe(err)}") from None


def load_config(path: str | Path | None, preset: str | None = None) -> PipelineConfig:
    """Read a JSON config file (None: all defaults) on top of a preset (`hippo_nav.system.presets`; None: the
    file's own `preset`, or none). Unknown keys and bad values are errors; so is a file naming another preset."""
    data = {} if path is None else _read_config_file(Path(path))
    source = "config" if path is None else str(path)
    if preset is not None:
        named = data.get("preset", preset)
        if named != preset:
            raise HippoNavError(
                f"{source}: names preset {_shown(named)}, and --preset {preset} was given; give one of them"
            )
        data = {"preset": preset, **data}
    return config_from_dict(data, source)


def _read_config_file(path: Path) -> dict[str, Any]:
    path = Path(path)
    # A folder, a FIFO or a device is refused before it is opened: opening a FIFO with no writer would wait
    # for ever.
    if path.exists() and not path.is_file():
        raise HippoNavError(f"{path}: not a config file (it is a folder or a special file); give a JSON file")
    try:
        text = read_text(path, "config file", MAX_SETTINGS_FILE_BYTES)
    except OSError as err:
        raise HippoNavError(f"{path}: cannot read the config file ({err.strerror or err})") from None
    if not text.strip():
        raise HippoNavError(
            f"{path}: the config file is empty; write {{}} for all defaults, or the sections to set"
        )
    try:
        data = json.loads(text, object_pairs_hook=_refuse_duplicates)
    except json.JSONDecodeError as err:
        raise HippoNavError(f"{path}:{err.lineno}: not valid JSON ({err.msg})") from None
    except _DuplicateKey as err:
        raise HippoNavError(f"{path}: key {_shown(err.key)} appears twice in one object; keep one") from None
    except RecursionError:  # the C parser's guard against nesting thousands of levels deep
        raise HippoNavError(
            f"{path}: nested too deeply to be a config (a config holds sections of settings)"
        ) from None
    except ValueError:  # an integer of more than 4 300 digits (Python's limit for int("…"))
        raise HippoNavError(
            f"{path}: holds an integer of thousands of digits; a setting takes a number of a few digits"
        ) from None
    if not isinstance(data, dict):
        raise HippoNavError(
            f"{path}: a config file holds one JSON object of sections, not a JSON {_json_kind(data)}"
        )
    return data


def _json_kind(value: object) -> str:
    return {list: "array", str: "string", bool: "boolean", type(None): "null"}.get(type(value), "number")


def write_config(config: PipelineConfig, path: str | Path) -> Path:
    """Write the fully resolved config (every default filled in) as JSON."""
    # Atomically (`hippo_nav.io.atomic`): a run stopped while writing leaves the old file or the whole new one.
    return write_text(path, json.dumps(resolved_config_dict(config), indent=2) + "\n")


def resolved_config_dict(config: PipelineConfig) -> dict[str, Any]:
    return json.loads(config.model_dump_json(by_alias=True))
