"""hippo_nav: brain-inspired visual SLAM (Zeng, Li & Si's entorhinal–hippocampal model), Rust engine inside.

```python
import hippo_nav
result = hippo_nav.run("runs/demo")            # the `hippo-nav run` command: built-in demo, or dataset=PATH
```
"""

from typing import Any

from hippo_nav._core import HippoNavError, __version__
from hippo_nav.engine import EngineConfig, SpatialMemory, SpatialReadout, ViewPatterns

# The pipeline pulls in OpenCV and matplotlib; load it on first use so `import hippo_nav` stays light.
_PIPELINE = {"Pipeline", "PipelineConfig", "load_config", "run"}


def __getattr__(name: str) -> Any:
    if name in _PIPELINE:
        from hippo_nav import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module 'hippo_nav' has no attribute {name!r}")


__all__ = [
    "EngineConfig",
    "HippoNavError",
    "Pipeline",
    "PipelineConfig",
    "SpatialMemory",
    "SpatialReadout",
    "ViewPatterns",
    "__version__",
    "load_config",
    "run",
]
