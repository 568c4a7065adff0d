"""The plug board: which implementation fills each plug point of the system, by the config's `parts` section.

| plug point | config | protocol | built-in |
|---|---|---|---|
| odometry | `parts.odometry` | `pipeline.frontend.Odometry` | `"stereo"`: `hippo_nav.vo.StereoOdometry` (`vo` section) |
| view cells | `parts.view_cells` | `view_cells.ViewDescriptor` | `"template"`: `TemplateViewCells` (`views` section); `"words"`: `WordViewCells` (`view_words` section) |
| loop closure | `parts.closure` | `closure.ClosureProposer` | `"view_cell_pnp"`: `ViewCellPnpClosure` (`closure` section) |

Each registry maps a name to a factory `(config, calibration) -> part`; adding an implementation is one
class in its package, its config section, and one line here (docs/architecture.md). A part can also be
given directly (`Pipeline(dataset, odometry=…, view_cells=…, closure=…)`), which bypasses the board.
The closure proposer is used in the map's geometric closure mode only (`map.closure = "Geometric"`); in
the paper's RatSLAM mode the map closes loops itself from the view-cell ids.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

from hippo_nav._core import HippoNavError
from hippo_nav.closure import ClosureProposer, ViewCellPnpClosure
from hippo_nav.datasets.base import StereoCalibration
from hippo_nav.map import ClosureMode
from hippo_nav.view_cells import TemplateViewCells, ViewDescriptor, WordViewCells
from hippo_nav.vo import StereoOdometry

if TYPE_CHECKING:
    from hippo_nav.pipeline.config import PipelineConfig
    from hippo_nav.pipeline.frontend import Odometry

P = TypeVar("P")
Factory = Callable[["PipelineConfig", StereoCalibration], P]

ODOMETRIES: dict[str, Factory[Odometry]] = {
    "stereo": lambda config, calibration: StereoOdometry(calibration, config.vo),
}
VIEW_CELLS: dict[str, Factory[ViewDescriptor]] = {
    "template": lambda config, calibration: TemplateViewCells.for_camera(config.views, calibration),
    "words": lambda config, calibration: WordViewCells.for_camera(config.view_words, calibration),
}
CLOSURE_PROPOSERS: dict[str, Factory[ClosureProposer]] = {
    # The keyframes' depths come from the same stereo pair as the odometry's: its correction applies.
    "view_cell_pnp": lambda config, calibration: ViewCellPnpClosure(
        calibration, config.closure, disparity_offset_px=config.vo.disparity_offset_px
    ),
}
REGISTRIES: dict[str, dict[str, Factory]] = {
    "odometry": ODOMETRIES,
    "view_cells": VIEW_CELLS,
    "closure": CLOSURE_PROPOSERS,
}
"""The registry of each field of the config's `parts` section."""


def _choice(plug: str, name: str) -> Factory:
    registry = REGISTRIES[plug]
    if name not in registry:
        raise HippoNavError(f"parts.{plug}: unknown {name!r}; choose from {', '.join(sorted(registry))}")
    return registry[name]


def make_odometry(config: PipelineConfig, calibration: StereoCalibration) -> Odometry:
    """The configured odometry for a camera."""
    return _choice("odometry", config.parts.odometry)(config, calibration)


def make_view_cells(config: PipelineConfig, calibration: StereoCalibration) -> ViewDescriptor:
    """The configured view descriptor for a camera."""
    return _choice("view_cells", config.parts.view_cells)(config, calibration)


def make_closure_proposer(config: PipelineConfig, calibration: StereoCalibration) -> ClosureProposer | None:
    """The configured closure proposer, or None when the map closes loops itself (RatSLAM mode)."""
    if config.map.closure != ClosureMode.GEOMETRIC:
        return None
    return _choice("closure", config.parts.closure)(config, calibration)
