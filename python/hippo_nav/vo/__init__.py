"""Stereo visual odometry (OpenCV features): `StereoOdometry(calibration, VoParams()).process(frame)`.

```python
from hippo_nav.vo import StereoOdometry, run_odometry
vo = StereoOdometry(dataset.calibration)
world_from_camera, steps = run_odometry(dataset)        # (n, 4, 4) and one VoStep per frame
```
"""

from hippo_nav.vo.odometry import STATUSES, StereoOdometry, VoParams, VoStep, planar_step, planar_velocities
from hippo_nav.vo.run import run_odometry

__all__ = [
    "STATUSES",
    "StereoOdometry",
    "VoParams",
    "VoStep",
    "planar_step",
    "planar_velocities",
    "run_odometry",
]
