"""Stereo visual odometry (OpenCV features): `StereoOdometry(calibration, VoParams()).process(frame)`.

```python
from hippo_nav.vo import StereoOdometry, run_odometry
vo = StereoOdometry(dataset.calibration)
world_from_camera, steps = run_odometry(dataset)        # (n, 4, 4) and one VoStep per frame
```

`ReplayOdometry(path, dataset)` (`hippo_nav.vo.replay`) replays another system's KITTI/TUM trajectory file
with the same `process(frame) -> VoStep` contract; `replay_odometry(path, align=...)` is the form
`hippo_nav.pipeline.run(..., odometry=)` takes (`hippo-nav run --odometry FILE`).
"""

from hippo_nav.vo.odometry import STATUSES, StereoOdometry, VoParams, VoStep, planar_step, planar_velocities
from hippo_nav.vo.replay import PoseFile, ReplayOdometry, read_pose_file, replay_odometry
from hippo_nav.vo.run import run_odometry

__all__ = [
    "STATUSES",
    "PoseFile",
    "ReplayOdometry",
    "StereoOdometry",
    "VoParams",
    "VoStep",
    "planar_step",
    "planar_velocities",
    "read_pose_file",
    "replay_odometry",
    "run_odometry",
]
