"""hippo_nav: brain-inspired visual SLAM (Zeng, Li & Si's entorhinal–hippocampal model), Rust engine inside."""

from hippo_nav._core import HippoNavError, __version__

__all__ = ["HippoNavError", "__version__"]
