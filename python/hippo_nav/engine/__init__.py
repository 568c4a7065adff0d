"""The neural engine: HD ring, grid modules, Bayesian fusion and the CA3 place torus (Rust)."""

from hippo_nav._core import find_bumps, fuse_modules
from hippo_nav.engine.config import MODULE_NAMES, N_MODULES, EngineConfig, GridConfig, HdConfig, PlaceConfig
from hippo_nav.engine.network import Bump, ModuleReadout, SpatialMemory, SpatialReadout, ViewPatterns
from hippo_nav.engine.recall import CompactView, GridBumpCode, HdBumpCode

__all__ = [
    "MODULE_NAMES",
    "N_MODULES",
    "Bump",
    "CompactView",
    "EngineConfig",
    "GridBumpCode",
    "GridConfig",
    "HdBumpCode",
    "HdConfig",
    "ModuleReadout",
    "PlaceConfig",
    "SpatialMemory",
    "SpatialReadout",
    "ViewPatterns",
    "find_bumps",
    "fuse_modules",
]
