"""Geometric loop closure: compact stereo keyframes per map vertex and the relative pose of a revisit.

When a familiar view (a local view cell, `hippo_nav.views`) suggests the agent is back at a place the map
knows, the pipeline asks the map which vertices a closure may join (`ExperienceMap.loop_candidates`) and
measures the pose of each candidate's keyframe from the current stereo frame (`LoopMeasurer.measure`):
ORB features of the current left image are matched to the keyframe's, and PnP with RANSAC on the
keyframe's stereo 3-D points gives `camera_cur_from_camera_key`. A closure is accepted only with enough
inliers; its planar part and covariance (from the reprojection Jacobian) become the loop link.

```python
from hippo_nav.closure import ClosureConfig, KeyframeExtractor, LoopMeasurer
extract = KeyframeExtractor(calibration, ClosureConfig())
key = extract(frame_a.left, frame_a.right)            # stored with a vertex (~10 kB)
now = extract(frame_b.left, frame_b.right)
measurement = LoopMeasurer(calibration, ClosureConfig()).measure(key, now)   # or None
measurement.agent_from_target, measurement.information                       # (x, y, yaw), (3, 3)
```
"""

from hippo_nav.closure.keyframes import ClosureConfig, Keyframe, KeyframeExtractor
from hippo_nav.closure.measure import LoopMeasurement, LoopMeasurer

__all__ = ["ClosureConfig", "Keyframe", "KeyframeExtractor", "LoopMeasurement", "LoopMeasurer"]
