"""hippo_nav: brain-inspired visual SLAM (Zeng, Li & Si's entorhinal–hippocampal model), Rust engine inside."""

from hippo_nav._core import HippoNavError, __version__
from hippo_nav.engine import EngineConfig, SpatialMemory, SpatialReadout, ViewPatterns

__all__ = ["EngineConfig", "HippoNavError", "SpatialMemory", "SpatialReadout", "ViewPatterns", "__version__"]
