"""Geometric loop closure: proposed and measured here, accepted or rejected by the experience map.

A closure proposer (`proposers.py`, the plug point) suggests a place the map knows and measures the pose of
the agent against it; the experience map (Rust, `hippo_nav.map`, docs/map.md) decides whether the closure
becomes a loop link. The built-in proposer, `ViewCellPnpClosure`, is driven by familiar view cells: it
keeps a compact stereo keyframe per map vertex (`keyframes.py`: SIFT features, or ORB's, with stereo 3-D
points) and measures a revisit by PnP of the stored 3-D points in the current image (`measure.py`: matches, PnP
with RANSAC, `camera_cur_from_camera_key`); a closure is proposed only with enough inliers, its planar part
and covariance (from the reprojection Jacobian) becoming the loop link.

```python
from hippo_nav.closure import ClosureConfig, KeyframeExtractor, LoopMeasurer
from hippo_nav.datasets import KittiOdometry
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence
dataset = KittiOdometry(demo_sequence(), DEMO_SEQUENCE, stop=3)
extract = KeyframeExtractor(dataset.calibration, ClosureConfig())
key = extract(dataset[0].left, dataset[0].right)             # stored with a vertex (~16 kB)
now = extract(dataset[2].left, dataset[2].right)
measurement, why = LoopMeasurer(dataset.calibration, ClosureConfig()).measure(key, now)
measurement.agent_from_target, measurement.information.shape, why   # ((≈ -2.8, ≈ 0.05, ≈ 0.0), (3, 3), "ok")
```
"""

from hippo_nav.closure.keyframes import ClosureConfig, Keyframe, KeyframeExtractor
from hippo_nav.closure.measure import LoopMeasurement, LoopMeasurer
from hippo_nav.closure.proposers import (
    ClosureAttempt,
    ClosureContext,
    ClosureProposer,
    ProposedClosure,
    ViewCellPnpClosure,
)

__all__ = [
    "ClosureAttempt",
    "ClosureConfig",
    "ClosureContext",
    "ClosureProposer",
    "Keyframe",
    "KeyframeExtractor",
    "LoopMeasurement",
    "LoopMeasurer",
    "ProposedClosure",
    "ViewCellPnpClosure",
]
