"""The whole system: stereo VO → spatial memory ← view cells → experience map, with results and figures.

- `system.py`: the per-frame algorithm (`SlamSystem.step`), its policies (`policies.py`) and the plug
  board that picks its parts (`parts.py`);
- `runner.py`: `Pipeline(dataset, config).run(out_dir)`, the runner around it (front-end threads in
  `frontend.py`, signals, progress, `observers.py`, the record in `records.py`), then `assemble.py`,
  `results.py` (metrics and the results folder) and `plots.py`;
- `config.py`: the typed config of a run.

```python
from hippo_nav.pipeline import Pipeline, PipelineConfig, open_input, run
result = run("runs/demo_12", stop=12, progress=False, overwrite=True)   # like `hippo-nav run`, 12 frames
result = Pipeline(open_input(stop=12), PipelineConfig(seed=1)).run(None)   # any StereoDataset; None: no files
result.metrics["errors"]["corrected"]["ate_2d_m"]
```
"""

from hippo_nav.pipeline.config import (
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
from hippo_nav.pipeline.observers import FrameEvent, NetworkActivity, Observer, RunInfo
from hippo_nav.pipeline.records import FrameRecord, RunRecord, RunResult
from hippo_nav.pipeline.runner import Pipeline, open_input, run
from hippo_nav.pipeline.system import Memory, SlamSystem, SystemStep

__all__ = [
    "CorrectionConfig",
    "FrameEvent",
    "FrameRecord",
    "InjectionConfig",
    "LesionConfig",
    "Memory",
    "MotionLimits",
    "NetworkActivity",
    "Observer",
    "OutputConfig",
    "PartsConfig",
    "Pipeline",
    "PipelineConfig",
    "RunInfo",
    "RunRecord",
    "RunResult",
    "SlamSystem",
    "SystemStep",
    "ViewSearchConfig",
    "config_from_dict",
    "load_config",
    "open_input",
    "run",
    "write_config",
]
