"""The closure's settings: the keyframe store and its measurements (`ClosureConfig`, the config's `closure`
section), the neighbour confirmation that view-cell and proximity proposals share (`closure.confirm`), and one
nested section per registered proposer (`closure.view_cell`, `closure.proximity`, …: each proposer's module owns
its model, `closure.PROPOSERS` lists them). `migrate_flat_closure` reads the flat keys of configs written before
the proposers had sections of their own (`closure.proximity_min_inliers` → `closure.proximity.min_inliers`,
`closure.birdseye = true` → `"birdseye"` in `parts.closure`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Literal

from pydantic import ConfigDict, Field

from hippo_nav._defaults import ConfigSection, move_keys
from hippo_nav.plugs import Part, PartSections


def _proposers() -> Mapping[str, Part[Callable[..., object]]]:
    from hippo_nav.closure.registry import PROPOSERS  # the registry imports the proposers, which import this

    return PROPOSERS


class ConfirmConfig(ConfigSection):
    """A measurement below a proposer's own bar is proposed only when a path neighbour of its vertex, measured
    from the same frame, puts that neighbour where the first measurement and the map do (`KeyframeStore.confirmed`):
    a wrong PnP pose from few matches is not repeated by a second keyframe."""

    model_config = ConfigDict(frozen=True)

    min_inliers: int = Field(
        10, ge=6, le=20000, description="PnP inliers the confirming neighbour's measurement needs"
    )
    max_distance_m: float = Field(
        7.0,
        gt=0.0,
        description="the confirming neighbour may be measured this far away (`max_distance_m` plus a vertex "
        "spacing; `keyframe_spacing_m` is added, as the nearest keyframed neighbour lies that much farther)",
    )
    agreement_m: float = Field(
        1.5,
        gt=0.0,
        description="a confirmed closure's two measurements put the neighbour within this of each "
        "other (pairs within 1 m of the truth on the `strong` renders: 0.1-1.2 m; with a wrong one: 2.4-4.9 m, "
        "docs/results.md)",
    )
    agreement_rad: float = Field(0.1, gt=0.0, description="… and within this heading")


class ClosureConfig(PartSections):
    """Geometric loop closure (the map's `closure` mode chooses whether it is used): what a vertex's keyframe
    keeps and how a measurement against it is made and judged, the spacing of accepted closures, the
    neighbour confirmation, and the sections of the proposers (`closure.PROPOSERS`)."""

    model_config = ConfigDict(frozen=True)
    registries: ClassVar[tuple[Any, ...]] = (_proposers,)

    orb_features: int = Field(
        500, ge=16, le=20000, description="features (ORB corners or SIFT blobs) detected per left image"
    )
    descriptor: Literal["orb", "sift"] = Field(
        "sift",
        description="what a keyframe's features are described by: SIFT (128 bytes, L2) or ORB (32 bytes, "
        "Hamming). Across a change of light, shadows, noise and blur (the `strong` renders) SIFT matches "
        "true revisits where ORB does not, and on real KITTI its measurements are about half as far off, at "
        "2-3x ORB's extraction time (docs/views.md, docs/results.md)",
    )
    keyframe_features: int = Field(
        300, ge=16, le=20000, description="strongest stereo features a keyframe keeps"
    )
    ratio_test: float = Field(0.8, gt=0.0, le=1.0, description="Lowe's ratio for descriptor matches")
    ransac_reprojection_px: float = Field(2.0, gt=0.0, description="PnP RANSAC inlier threshold")
    ransac_iterations: int = Field(300, ge=10, le=100_000)
    min_inliers: int = Field(
        30, ge=6, le=20000, description="fewer PnP inliers reject a closure (unrelated places give < 10)"
    )
    min_inlier_ratio: float = Field(
        0.25, ge=0.0, le=1.0, description="inliers / descriptor matches below this reject a closure"
    )
    max_distance_m: float = Field(
        4.0,
        gt=0.0,
        description="a keyframe measured farther away is rejected: closures join places within 4 m (the "
        "vertex spacing is ~3 m); far keyframes are seen at grazing angles with few, weak matches, and their "
        "range is measured worst (one measured within 5 m was 5.85 m away in truth, on the 00 render)",
    )
    max_sigma_m: float = Field(
        1.5,
        gt=0.0,
        description="a measurement whose position is less certain than this (largest σ of the covariance the "
        "map gets, m) is refused (noted `uncertain`): on the 00 render at `strong` the accepted measurements "
        "3 m or more off had 1.5-1.6 m, those within 0.6 m of the truth mostly under 1.3 m",
    )
    sigma_floor_xy_m: float = Field(0.05, gt=0.0, description="least position uncertainty of a loop link")
    sigma_floor_yaw_rad: float = Field(0.005, gt=0.0, description="least heading uncertainty of a loop link")
    covariance_inflation: float = Field(
        4.0,
        ge=1.0,
        le=1e6,
        description="factor on the measured pose's covariance (for errors the model leaves out)",
    )
    pixel_sigma_px: float = Field(
        0.7, gt=0.0, le=10.0, description="standard deviation of an ORB corner's position (px)"
    )
    disparity_sigma_px: float = Field(
        0.3, gt=0.0, le=10.0, description="standard deviation of a stereo disparity (px)"
    )
    spacing_m: float = Field(
        3.0, ge=0.0, description="travel (m) between accepted closures; closer ones add little"
    )
    keyframe_spacing_m: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        description="a new vertex keeps a stereo keyframe only when the last one kept was made at least this "
        "far back along the odometry (0: every vertex keeps one); proposers measure the vertices that keep "
        'one. A SIFT keyframe is about a quarter of a real KITTI frame\'s CPU (docs/results.md, "Cost")',
    )
    stereo_row_tolerance_px: float = Field(1.5, gt=0.0)
    refine_stereo: bool = Field(
        True,
        description="refine each stereo match with a row-sheared window (as the VO does, docs/vo.md): KLT's "
        "square window is biased on a slanted road, which made measured links a few percent long",
    )
    stereo_guess_depth_m: float = Field(20.0, gt=0.0, description="depth whose disparity starts stereo KLT")
    forward_backward_px: float = Field(1.0, gt=0.0, description="max left-right-left KLT error")
    confirm: ConfirmConfig = Field(default_factory=ConfirmConfig)


# Flat keys of the `closure` section before each proposer had a section of its own → where they live now.
_MOVED = {
    "closure_spacing_m": ("spacing_m",),
    "candidates_per_frame": ("view_cell", "candidates_per_frame"),
    "anchor_neighbours": ("view_cell", "anchor_neighbours"),
    "view_cell_confirmed_min_inliers": ("view_cell", "confirmed_min_inliers"),
    "proximity_confirm": ("proximity", "confirm"),
    "proximity_confirm_min_inliers": ("confirm", "min_inliers"),
    "proximity_confirm_max_distance_m": ("confirm", "max_distance_m"),
    "proximity_agreement_m": ("confirm", "agreement_m"),
    "proximity_agreement_rad": ("confirm", "agreement_rad"),
}
_PREFIXED = ("proximity", "birdseye", "relocalisation")  # `<name>_<field>` → `<name>.<field>`


def migrate_flat_closure(
    closure: dict[str, object], proposers: list[str]
) -> tuple[dict[str, object], list[str], list[str]]:
    """(the `closure` section with flat keys moved to their sections, the proposers with the old on/off
    switches `proximity` and `birdseye` applied, one line per key moved). A key already at its new place
    wins over its old spelling."""
    closure, proposers, moved = dict(closure), list(proposers), []
    for switch in ("proximity", "birdseye"):
        if isinstance(closure.get(switch), bool):
            on = closure.pop(switch)
            if on and switch not in proposers:
                proposers.append(switch)
            if not on and switch in proposers:
                proposers.remove(switch)
            moved.append(f"closure.{switch} = {str(on).lower()} → parts.closure {proposers}")
    closure, renamed = move_keys(closure, _new_place)
    moved += [f"closure.{old} → closure.{new}" for old, new in renamed]
    return closure, proposers, moved


def _new_place(key: str) -> tuple[str, ...] | None:
    """Where a flat key of the `closure` section lives now (None: it has not moved)."""
    if key in _MOVED:
        return _MOVED[key]
    prefix = next((p for p in _PREFIXED if key.startswith(f"{p}_")), None)
    return None if prefix is None else (prefix, key[len(prefix) + 1 :])
