"""The camera front end of the pipeline: stereo VO and local view cells, built from config sections.

The pipeline relies on this much of them:
- odometry: `.process(frame) -> step` with `step.camera_prev_from_camera_cur` (4×4, SE(3)) and
  `step.status` (str, "ok" when the VO trusts the step);
- view cells: `.template_from_image(gray) -> template`, `.observe(template) -> observation` with
  `status`, `cell_id` (None when uninformative), `is_new`, `difference`, `relative_heading_rad`;
  `len(view_cells)` is the number of cells.
"""

from __future__ import annotations

from typing import Any

from hippo_nav._core import HippoNavError


def make_odometry(calibration: Any, params: dict[str, Any]) -> Any:
    """The stereo VO for `calibration`, with `params` (the config's `vo` section) overriding its defaults."""
    from pydantic import ValidationError

    from hippo_nav.pipeline.config import describe_validation_error
    from hippo_nav.vo import StereoOdometry, VoParams

    try:
        vo_params = VoParams.model_validate(params)
    except ValidationError as err:
        raise HippoNavError(f"config section vo: {describe_validation_error(err)}") from None
    return StereoOdometry(calibration, vo_params)


def make_view_cells(params: dict[str, Any], calibration: Any = None) -> Any:
    """Local view cells, with `params` (the config's `views` section) overriding their defaults.

    Unless the section sets `field_of_view_rad`, it is the camera's (from `calibration`), so that template
    shifts convert to the right relative heading on any camera, not only KITTI's."""
    from hippo_nav.views import ViewCellConfig, ViewCells, field_of_view_rad

    params = dict(params)
    if calibration is not None and "field_of_view_rad" not in params:
        params["field_of_view_rad"] = field_of_view_rad(calibration.fx, calibration.image_size_px[0])
    from pydantic import ValidationError

    from hippo_nav.pipeline.config import describe_validation_error

    try:
        view_params = ViewCellConfig.model_validate(params)
    except ValidationError as err:
        raise HippoNavError(f"config section views: {describe_validation_error(err)}") from None
    return ViewCells(view_params)


def resolved_frontend_params(odometry: Any, view_cells: Any) -> dict[str, Any]:
    """The front end's parameters with every default filled in (for the resolved config written with the
    results); a part given without a pydantic config (a custom front end) is left out."""
    resolved = {}
    for section, part, attr in (("vo", odometry, "params"), ("views", view_cells, "config")):
        params = getattr(part, attr, None)
        if hasattr(params, "model_dump"):
            resolved[section] = params.model_dump(mode="json")
    return resolved
