"""The whole system: stereo VO → spatial memory ← view cells → experience map, with results and figures.

```python
from hippo_nav.pipeline import Pipeline, PipelineConfig, run
result = run("runs/demo")                                   # the built-in synthetic demo, like `hippo-nav run`
result = Pipeline(dataset, PipelineConfig(seed=1)).run("runs/x")   # any StereoDataset
result.metrics["errors"]["corrected"]["ate_2d_m"]
```
"""

from hippo_nav.pipeline.config import (
    CorrectionConfig,
    InjectionConfig,
    LesionConfig,
    MotionLimits,
    OutputConfig,
    PipelineConfig,
    config_from_dict,
    load_config,
    write_config,
)
from hippo_nav.pipeline.pipeline import Pipeline, open_input, planar_step, run
from hippo_nav.pipeline.records import FrameRecord, RunRecord, RunResult

__all__ = [
    "CorrectionConfig",
    "FrameRecord",
    "InjectionConfig",
    "LesionConfig",
    "MotionLimits",
    "OutputConfig",
    "Pipeline",
    "PipelineConfig",
    "RunRecord",
    "RunResult",
    "config_from_dict",
    "load_config",
    "open_input",
    "planar_step",
    "run",
    "write_config",
]
