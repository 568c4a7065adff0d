"""The experience map (cognitive map, docs/spec.md §8) and its two correctors, from Python.

The engine is Rust (`crates/hippo_map`); this module adds typed parameters and small conveniences.

- `ExperienceMap`: driven once per camera frame with `on_frame(view_cell_id, place_code_rad,
  heading_code_rad, odometry_step, elapsed_s, loop_closure=None)`; `odometry_step` is the odometry's
  planar step `previous_frame_from_frame` as `(dx_forward_m, dy_left_m, dyaw_rad)`; `loop_closure` a
  measured closure `(target_vertex, agent_from_target, information)`. Returns a frozen `MapFrameOutcome`:
  the current `vertex`, whether one was `created`, the `loop_closure` `(from, to)` added, why a closure
  was rejected (`rejected_closure`), the `ambiguous_candidates` (RatSLAM mode), `relocalized`,
  `world_from_agent` and `vertex_from_agent`. `loop_candidates(vertices, step)` lists the vertices a
  closure at the next frame may join; `vertices_near(radius_m, step)` the vertices around the agent.
- `correct(method="least_squares" | "relaxation")` corrects the vertex poses: sparse Levenberg–Marquardt
  on SE(2) (optionally with a robust loss on loop links) or RatSLAM-style relaxation passes. It returns a
  frozen `CorrectionReport`; `PoseGraph.optimize` a `SolveReport` and `PoseGraph.relax` a
  `RelaxationReport`. Reports read by attribute (`report.final_chi2`), also like a dict
  (`report["final_chi2"]`), and `as_dict()` gives a plain dict for JSON.
- `poses()` gives `(N, 3)` arrays of `(x_m, y_m, yaw_rad)`; `export()` the whole graph as arrays;
  `save`/`load` a versioned, checksummed file; `PoseGraph` reads and writes g2o files.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Any

from pydantic import ConfigDict, Field

from hippo_nav._core import (
    CorrectionReport,
    ExperienceMap,
    MapFrameOutcome,
    PoseGraph,
    RelaxationReport,
    SolveReport,
)
from hippo_nav._defaults import ConfigSection, rust_default

__all__ = [
    "AmbiguityPolicy",
    "ClosureMode",
    "CorrectionReport",
    "ExperienceMap",
    "MapFrameOutcome",
    "MapParams",
    "OnlineCorrection",
    "PoseGraph",
    "RelaxationReport",
    "SolveReport",
    "new_experience_map",
    "read_g2o",
]


class AmbiguityPolicy(str, Enum):
    """What to do when several vertices match a frame (RatSLAM closure)."""

    NEAREST_POSE = "NearestPose"
    NEAREST_CODE = "NearestCode"
    CREATE_VERTEX = "CreateVertex"


class ClosureMode(str, Enum):
    """How loop closures are found: measured by stereo geometry (default) or the paper's RatSLAM rule."""

    GEOMETRIC = "Geometric"
    RATSLAM = "RatSlam"


class OnlineCorrection(str, Enum):
    """The correction run while the map is built."""

    NONE = "None"
    RELAXATION = "Relaxation"
    LEAST_SQUARES = "LeastSquares"


def _default(name: str) -> Any:
    # One source of defaults: the Rust `MapParams::default()`.
    return rust_default("map", name)


class MapParams(ConfigSection):
    """Creation, closure and correction settings of the experience map (defaults come from the Rust
    engine; their meaning is documented on `hippo_map::MapParams` and in docs/map.md)."""

    model_config = ConfigDict(frozen=True)

    place_threshold_rad: float = Field(_default("place_threshold_rad"), gt=0)
    heading_threshold_rad: float = Field(_default("heading_threshold_rad"), gt=0)
    max_vertex_spacing_m: float = Field(_default("max_vertex_spacing_m"), gt=0)
    closure: ClosureMode = ClosureMode(_default("closure"))
    ambiguity: AmbiguityPolicy = AmbiguityPolicy(_default("ambiguity"))
    min_loop_separation_m: float = Field(_default("min_loop_separation_m"), ge=0)
    loop_gate_m: float = Field(_default("loop_gate_m"), gt=0)
    loop_gate_per_m: float = Field(_default("loop_gate_per_m"), ge=0)
    loop_gate_yaw_rad: float = Field(_default("loop_gate_yaw_rad"), gt=0)
    loop_gate_yaw_rad_per_m: float = Field(_default("loop_gate_yaw_rad_per_m"), ge=0)
    max_loop_chi2: float = Field(_default("max_loop_chi2"), gt=0)
    online_correction: OnlineCorrection = OnlineCorrection(_default("online_correction"))
    online_relaxation_passes: int = Field(_default("online_relaxation_passes"), ge=0, le=1_000_000)
    relaxation_gain: float = Field(_default("relaxation_gain"), gt=0, lt=1)
    online_max_iterations: int = Field(_default("online_max_iterations"), ge=1, le=100_000)
    link_sigma_xy_m: float = Field(_default("link_sigma_xy_m"), gt=0)
    link_sigma_yaw_rad: float = Field(_default("link_sigma_yaw_rad"), gt=0)
    odometry_sigma_xy_per_m: float = Field(_default("odometry_sigma_xy_per_m"), ge=0)
    odometry_sigma_yaw_rad_per_m: float = Field(_default("odometry_sigma_yaw_rad_per_m"), ge=0)
    ratslam_loop_sigma_xy_m: float = Field(_default("ratslam_loop_sigma_xy_m"), gt=0)
    ratslam_loop_sigma_yaw_rad: float = Field(_default("ratslam_loop_sigma_yaw_rad"), gt=0)


def new_experience_map(params: MapParams | None = None) -> ExperienceMap:
    """An empty experience map with the given parameters (defaults when None)."""
    params = params or MapParams()
    return ExperienceMap(params.model_dump_json())


def read_g2o(path: str | Path) -> PoseGraph:
    """Read a g2o 2-D pose graph (VERTEX_SE2 / EDGE_SE2 / FIX)."""
    return PoseGraph.read_g2o(Path(path))
