"""The camera front end of the pipeline: odometry and local view cells, as protocols and from config.

Anything with these methods can stand in for the built-in parts (`Pipeline(..., odometry=, view_cells=)`):
- `Odometry.process(frame) -> OdometryStep` with `camera_prev_from_camera_cur` (4×4 SE(3): the current
  camera's pose in the previous camera's frame, identity on the first frame) and `status` ("ok" when the
  step was measured and trusted, "first" on the first frame);
- `ViewCellFrontEnd.template_from_image(gray) -> template`, `.observe(template, candidates) -> observation`
  (`status`, `cell_id` — None when uninformative —, `is_new`, `difference`, `relative_heading_rad`), and
  `len(view_cells)`, the number of cells.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from hippo_nav.datasets.base import StereoCalibration, StereoFrame
from hippo_nav.views import ViewCellConfig, ViewCells, field_of_view_rad
from hippo_nav.vo import StereoOdometry, VoParams


class OdometryStep(Protocol):
    @property
    def camera_prev_from_camera_cur(self) -> np.ndarray: ...

    @property
    def status(self) -> str: ...


class Odometry(Protocol):
    def process(self, frame: StereoFrame) -> OdometryStep: ...


class ViewObservationLike(Protocol):
    @property
    def status(self) -> str: ...

    @property
    def cell_id(self) -> int | None: ...

    @property
    def is_new(self) -> bool: ...

    @property
    def difference(self) -> float: ...

    @property
    def relative_heading_rad(self) -> float: ...


class ViewCellFrontEnd(Protocol):
    def template_from_image(self, gray: np.ndarray) -> np.ndarray: ...

    def observe(
        self, template: np.ndarray, candidates: Sequence[int] | None = None
    ) -> ViewObservationLike: ...

    def __len__(self) -> int: ...


def tracked_pixels(odometry: object) -> np.ndarray | None:
    """(n, 2) left-image pixels of the features `odometry` tracks from its last frame, or None when it has
    no `tracked_pixels` (an array, or a method returning one): a replayed or custom odometry."""
    public = getattr(odometry, "tracked_pixels", None)
    pixels = public() if callable(public) else public
    if pixels is None:
        return None
    pixels = np.asarray(pixels, dtype=np.float64)
    return pixels.reshape(-1, 2) if pixels.size % 2 == 0 else None


def make_odometry(calibration: StereoCalibration, params: VoParams) -> StereoOdometry:
    """The stereo VO for `calibration` with the config's `vo` section."""
    return StereoOdometry(calibration, params)


def make_view_cells(params: ViewCellConfig, calibration: StereoCalibration | None = None) -> ViewCells:
    """Local view cells with the config's `views` section.

    Unless the section sets `field_of_view_rad`, it is the camera's (from `calibration`), so that template
    shifts convert to the right relative heading on any camera, not only KITTI's."""
    if calibration is not None and "field_of_view_rad" not in params.model_fields_set:
        fov = field_of_view_rad(calibration.fx, calibration.image_size_px[0])
        params = params.model_copy(update={"field_of_view_rad": fov})
    return ViewCells(params)


def resolved_frontend_params(odometry: object, view_cells: object) -> dict[str, Any]:
    """The front end's parameters with every default filled in (for the resolved config written with the
    results); a part given without a pydantic config (a custom front end) is left out."""
    resolved = {}
    for section, part, attr in (("vo", odometry, "params"), ("views", view_cells, "config")):
        params = getattr(part, attr, None)
        if params is not None and hasattr(params, "model_dump"):
            resolved[section] = params.model_dump(mode="json")
    return resolved
