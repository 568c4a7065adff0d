"""The runner around the per-frame system (`hippo_nav.system`), with results and figures.

- `runner.py`: `Pipeline(dataset, config).run(out_dir)` (front-end threads in `frontend.py`, signals,
  progress, `observers.py`, the record in `records.py`), then `assemble.py`, `results.py` (metrics and the
  results folder) and `plots.py`;
- the system's names (`SlamSystem`, `PipelineConfig`, `config_from_dict`, …) are here too, so one import
  serves a script.

```python
from hippo_nav.pipeline import Pipeline, PipelineConfig, open_input, run
result = run("runs/demo_12", stop=12, progress=False, overwrite=True)   # like `hippo-nav run`, 12 frames
result = Pipeline(open_input(stop=12), PipelineConfig(seed=1)).run(None)   # any StereoDataset; None: no files
result.metrics["errors"]["corrected"]["ate_2d_m"]
```
"""

from hippo_nav.pipeline.observers import FrameEvent, NetworkActivity, Observer, RunInfo
from hippo_nav.pipeline.records import RunRecord, RunResult
from hippo_nav.pipeline.runner import Pipeline, open_input, run
from hippo_nav.system import (
    CorrectionConfig,
    FrameRecord,
    InjectionConfig,
    LesionConfig,
    Memory,
    MotionLimits,
    OutputConfig,
    PartsConfig,
    PipelineConfig,
    SlamSystem,
    SystemStep,
    ViewSearchConfig,
    config_from_dict,
    load_config,
    parts,
    write_config,
)

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
    "parts",
    "run",
    "write_config",
]
