"""Sweeps: many runs of the pipeline over a cross-product of settings, on Ray, resumable (`hippo-nav sweep`).

- `space.py`: the axes (config overrides, seeds, lesions, sequences, odometries) from the command line or a
  TOML/YAML sweep file, expanded into runs with stable ids;
- `worker.py`: one run on a Ray worker — `hippo_nav.pipeline.run`, its results folder and `manifest.json`;
- `manifest.py`: what a manifest holds (provenance) and how it is written (atomically);
- `scheduler.py`: the driver — resume, Ray on this machine or a cluster, progress, failures, Ctrl-C.

Ray is imported only when runs are dispatched (`pip install 'hippo-nav[sweep]'`); the space, the plan and
the manifests need nothing beyond hippo_nav.

```python
from hippo_nav.sweep import build_space
space = build_space(sets=["views.novelty_threshold=0.40,0.45"], lesions="none,dorsal", seeds="0-1")
[run.run_id for run in space.runs()][:2]   # 8 runs, ids like 'vo_novelty_threshold=0.4_s0-1a2b3c4d'
```
"""

from hippo_nav.sweep.manifest import MANIFEST, RUNS_DIR, read_manifest
from hippo_nav.sweep.scheduler import SweepOptions, SweepSummary, plan, run_sweep
from hippo_nav.sweep.space import RunSpec, SweepSpace, build_space

__all__ = [
    "MANIFEST",
    "RUNS_DIR",
    "RunSpec",
    "SweepOptions",
    "SweepSpace",
    "SweepSummary",
    "build_space",
    "plan",
    "read_manifest",
    "run_sweep",
]
