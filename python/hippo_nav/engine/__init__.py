"""The neural engine: HD ring, grid modules, Bayesian fusion and the CA3 place torus (Rust); `drive` runs it
along a trajectory's planar odometry with no camera (the paper's path-integration experiments)."""

from hippo_nav._core import find_bumps, fuse_modules
from hippo_nav.engine.config import MODULE_NAMES, N_MODULES, EngineConfig, GridConfig, HdConfig, PlaceConfig
from hippo_nav.engine.drive import DriveResult, PlanarOdometry, drive, planar_odometry, planar_track
from hippo_nav.engine.network import Bump, ModuleReadout, SpatialMemory, SpatialReadout, ViewPatterns
from hippo_nav.engine.recall import CompactView, GridBumpCode, HdBumpCode

__all__ = [
    "MODULE_NAMES",
    "N_MODULES",
    "Bump",
    "CompactView",
    "DriveResult",
    "EngineConfig",
    "GridBumpCode",
    "GridConfig",
    "HdBumpCode",
    "HdConfig",
    "ModuleReadout",
    "PlaceConfig",
    "PlanarOdometry",
    "SpatialMemory",
    "SpatialReadout",
    "ViewPatterns",
    "drive",
    "find_bumps",
    "fuse_modules",
    "planar_odometry",
    "planar_track",
]
