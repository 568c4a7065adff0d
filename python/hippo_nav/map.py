"""The experience map (cognitive map, SPEC §8) and its two correctors, from Python.

The engine is Rust (`crates/hippo_map`); this module adds typed parameters and small conveniences.

- `ExperienceMap`: driven once per camera frame with `on_frame(view_cell_id, place_code_rad,
  heading_code_rad, odometry_step, elapsed_s)`; `odometry_step` is the VO's planar step
  `previous_frame_from_frame` as `(dx_forward_m, dy_left_m, dyaw_rad)`. Returns a dict with the current
  `vertex`, whether one was `created`, the `loop_closure` `(from, to)` added, the `ambiguous_candidates`
  (all matching vertices when more than one matched), `relocalized`, and `world_from_agent`.
- `correct(method="least_squares" | "relaxation")` corrects the vertex poses: sparse Levenberg–Marquardt
  on SE(2) (optionally with a robust loss on loop links) or RatSLAM-style relaxation passes.
- `poses()` gives `(N, 3)` arrays of `(x_m, y_m, yaw_rad)`; `export()` the whole graph as arrays;
  `save`/`load` a versioned, checksummed file; `PoseGraph` reads and writes g2o files.
"""

from __future__ import annotations

import json
from enum import Enum
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from hippo_nav._core import ExperienceMap, PoseGraph

__all__ = ["AmbiguityPolicy", "ExperienceMap", "MapParams", "PoseGraph", "new_experience_map", "read_g2o"]

# One source of defaults: the Rust `MapParams::default()`.
_RUST_DEFAULTS = json.loads(ExperienceMap.default_params_json())


class AmbiguityPolicy(str, Enum):
    """What to do when several vertices match a frame."""

    NEAREST_POSE = "NearestPose"
    NEAREST_CODE = "NearestCode"
    CREATE_VERTEX = "CreateVertex"


class MapParams(BaseModel):
    """Creation and correction settings of the experience map (defaults come from the Rust engine)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    place_threshold_rad: float = Field(_RUST_DEFAULTS["place_threshold_rad"], gt=0)
    heading_threshold_rad: float = Field(_RUST_DEFAULTS["heading_threshold_rad"], gt=0)
    ambiguity: AmbiguityPolicy = AmbiguityPolicy(_RUST_DEFAULTS["ambiguity"])
    online_relaxation_passes: int = Field(_RUST_DEFAULTS["online_relaxation_passes"], ge=0)
    relaxation_gain: float = Field(_RUST_DEFAULTS["relaxation_gain"], gt=0, lt=1)
    link_sigma_xy_m: float = Field(_RUST_DEFAULTS["link_sigma_xy_m"], gt=0)
    link_sigma_yaw_rad: float = Field(_RUST_DEFAULTS["link_sigma_yaw_rad"], gt=0)


def new_experience_map(params: MapParams | None = None) -> ExperienceMap:
    """An empty experience map with the given parameters (defaults when None)."""
    params = params or MapParams()
    return ExperienceMap(params.model_dump_json())


def read_g2o(path: str | Path) -> PoseGraph:
    """Read a g2o 2-D pose graph (VERTEX_SE2 / EDGE_SE2 / FIX)."""
    return PoseGraph.read_g2o(Path(path))
