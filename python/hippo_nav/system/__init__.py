"""The per-frame SLAM system, apart from anything that runs it: stereo odometry step → spatial memory ← view
cells → experience map, one frame at a time (`slam.SlamSystem`), its policies (`policies.py`), the plug
board that picks its parts (`parts.py`), its typed config (`config.py`) and what it reports per frame
(`records.py`). It has no threads, signals, progress bars or files; the runner (`hippo_nav.pipeline`) loads
frames, measures the odometry ahead, records, shows progress, feeds observers and writes results.

```python
from hippo_nav.pipeline import open_input
from hippo_nav.system import SlamSystem
from hippo_nav.vo import StereoOdometry

dataset = open_input(stop=5)
system, odometry = SlamSystem(dataset.calibration), StereoOdometry(dataset.calibration)
for frame in dataset:
    step = odometry.process(frame)
    decided = system.step(frame, step.camera_prev_from_camera_cur, step.status)
decided.record.frame_index, system.frames                  # (4, 5)
```
"""

from hippo_nav.system import parts
from hippo_nav.system.config import (
    CorrectionConfig,
    InjectionConfig,
    LesionConfig,
    MotionLimits,
    OutputConfig,
    PartsConfig,
    PipelineConfig,
    ViewSearchConfig,
    config_from_dict,
    load_config,
    write_config,
)
from hippo_nav.system.records import STAGES, FrameRecord, StageTimer
from hippo_nav.system.slam import Memory, SlamSystem, SystemStep

__all__ = [
    "STAGES",
    "CorrectionConfig",
    "FrameRecord",
    "InjectionConfig",
    "LesionConfig",
    "Memory",
    "MotionLimits",
    "OutputConfig",
    "PartsConfig",
    "PipelineConfig",
    "SlamSystem",
    "StageTimer",
    "SystemStep",
    "ViewSearchConfig",
    "config_from_dict",
    "load_config",
    "parts",
    "write_config",
]
