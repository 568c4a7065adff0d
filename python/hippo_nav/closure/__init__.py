"""Geometric loop closure: proposed and measured here, accepted or rejected by the experience map.

A chain of proposers (`chain.ClosureChain`, the config's `parts.closure` in order) suggests places the map
knows and measures the pose of the agent against them; the experience map (Rust, `hippo_nav.map`,
docs/map.md) decides whether the first proposal becomes a loop link. Every proposer measures against one
keyframe store (`store.KeyframeStore`): a compact stereo keyframe per map vertex (`keyframes.py`: SIFT
features, or ORB's, with stereo 3-D points), a revisit measured by PnP of the stored 3-D points in the current
image (`measure.py`: matches, PnP with RANSAC, `camera_cur_from_camera_key`); a closure is proposed only with
enough inliers, its planar part and covariance (from the reprojection Jacobian) becoming the loop link.

The proposers (`PROPOSERS`, one module each, each with its config section `closure.<name>`): `view_cell`
(familiar views), `proximity` (the vertex where the odometry puts the agent), `home` (where the session began,
once the agent has been away), `relocalisation` (a session inside a loaded map), `birdseye` (stereo structure
from above, for streets driven the other way), `sequence` (the last views along the path matched in order, for
revisits under other light that a drifting odometry misplaces).

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

from hippo_nav.closure.base import (
    NO_ATTEMPT,
    ClosureAttempt,
    ClosureContext,
    ClosureProposer,
    ProposedClosure,
)
from hippo_nav.closure.chain import ClosureChain
from hippo_nav.closure.config import ClosureConfig, ConfirmConfig
from hippo_nav.closure.keyframes import Keyframe, KeyframeExtractor
from hippo_nav.closure.measure import LoopMeasurement, LoopMeasurer
from hippo_nav.closure.registry import DEFAULT_PROPOSERS, PROPOSERS
from hippo_nav.closure.store import KeyframeStore

__all__ = [
    "DEFAULT_PROPOSERS",
    "NO_ATTEMPT",
    "PROPOSERS",
    "ClosureAttempt",
    "ClosureChain",
    "ClosureConfig",
    "ClosureContext",
    "ClosureProposer",
    "ConfirmConfig",
    "Keyframe",
    "KeyframeExtractor",
    "KeyframeStore",
    "LoopMeasurement",
    "LoopMeasurer",
    "ProposedClosure",
]
