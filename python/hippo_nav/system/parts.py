"""The plug board: which implementation fills each plug point of the system, by the config's `parts` section.

| plug point | config | protocol | registry (its package) | built-in |
|---|---|---|---|---|
| odometry | `parts.odometry` | `vo.Odometry` | `vo.ODOMETRIES` | `"stereo"` (`vo` section) |
| view cells | `parts.view_cells` | `view_cells.ViewDescriptor` | `view_cells.DESCRIPTORS` | `"words"` (`view_words`), `"template"` (`views`) |
| loop closure | `parts.closure` (a list, in order) | `closure.ClosureProposer` | `closure.PROPOSERS` | `"relocalisation"`, `"view_cell"`, `"proximity"`, `"birdseye"` (`closure.<name>`) |

Each registry maps a name to a `Part` (`hippo_nav.plugs`): its factory, its config model and its section, from
which `PipelineConfig` derives the part's settings. Adding an implementation is its module in its package and
one line in that package's registry (docs/architecture.md). A part can also be given directly
(`Pipeline(dataset, odometry=…, view_cells=…, closure=…)`), which bypasses the board. The closure chain is used
in the map's geometric closure mode only (`map.closure = "Geometric"`); in the paper's RatSLAM mode the map
closes loops itself from the view-cell ids.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, TypeVar

from hippo_nav._core import HippoNavError
from hippo_nav.closure import PROPOSERS, ClosureChain, KeyframeStore
from hippo_nav.datasets.base import StereoCalibration
from hippo_nav.map import ClosureMode
from hippo_nav.plugs import Part
from hippo_nav.view_cells import DESCRIPTORS, ViewDescriptor
from hippo_nav.vo import ODOMETRIES, Odometry, VoParams

F = TypeVar("F", bound=Callable[..., object])

if TYPE_CHECKING:
    from hippo_nav.system.config import PipelineConfig

# The registries by plug point, under their historical names too (`parts.VIEW_CELLS` is `DESCRIPTORS`).
VIEW_CELLS = DESCRIPTORS
CLOSURE_PROPOSERS = PROPOSERS
REGISTRIES: dict[str, Mapping[str, Part[Callable[..., object]]]] = {
    "odometry": ODOMETRIES,
    "view_cells": DESCRIPTORS,
    "closure": PROPOSERS,
}
"""The registry of each field of the config's `parts` section."""


def _choice(registry: Mapping[str, Part[F]], plug: str, name: str) -> Part[F]:
    if name not in registry:
        raise HippoNavError(f"parts.{plug}: unknown {name!r}; choose from {', '.join(sorted(registry))}")
    return registry[name]


def make_odometry(config: PipelineConfig, calibration: StereoCalibration) -> Odometry:
    """The configured odometry for a camera."""
    part = _choice(ODOMETRIES, "odometry", config.parts.odometry)
    odometry: Odometry = part.build(config.section(part.section), calibration)
    return odometry


def make_view_cells(config: PipelineConfig, calibration: StereoCalibration) -> ViewDescriptor:
    """The configured view descriptor for a camera."""
    part = _choice(DESCRIPTORS, "view_cells", config.parts.view_cells)
    descriptor: ViewDescriptor = part.build(config.section(part.section), calibration)
    return descriptor


def make_closure(config: PipelineConfig, calibration: StereoCalibration) -> ClosureChain | None:
    """The configured closure chain, or None when the map closes loops itself (RatSLAM mode)."""
    if config.map.closure != ClosureMode.GEOMETRIC:
        return None
    closure = config.closure
    # The keyframes' depths come from the same stereo pair as the odometry's: its correction applies.
    offset_px = config.typed_section("vo", VoParams).disparity_offset_px
    store = KeyframeStore(calibration, closure, disparity_offset_px=offset_px)
    proposers = []
    for name in config.parts.closure:
        part = _choice(PROPOSERS, "closure", name)
        proposers.append((name, part.build(closure.section(part.section))))
    return ClosureChain(store, proposers)


__all__ = [
    "CLOSURE_PROPOSERS",
    "REGISTRIES",
    "VIEW_CELLS",
    "make_closure",
    "make_odometry",
    "make_view_cells",
]
