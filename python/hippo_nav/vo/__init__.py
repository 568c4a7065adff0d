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

from collections.abc import Callable

from hippo_nav.datasets.base import StereoCalibration
from hippo_nav.plugs import Part
from hippo_nav.vo.base import Odometry, OdometryStep
from hippo_nav.vo.odometry import STATUSES, StereoOdometry, VoStep, planar_step, planar_velocities
from hippo_nav.vo.replay import PoseFile, ReplayOdometry, read_pose_file, replay_odometry
from hippo_nav.vo.run import run_odometry
from hippo_nav.vo.settings import VoParams, WindowConfig

OdometryFactory = Callable[..., Odometry]  # (its config section, the camera) → the odometry


def _stereo(config: VoParams, calibration: StereoCalibration) -> StereoOdometry:
    return StereoOdometry(calibration, config)


# The odometries by name (`parts.odometry`); the protocol is `base.Odometry`.
ODOMETRIES: dict[str, Part[OdometryFactory]] = {"stereo": Part(_stereo, VoParams, "vo")}

__all__ = [
    "ODOMETRIES",
    "STATUSES",
    "Odometry",
    "OdometryFactory",
    "OdometryStep",
    "PoseFile",
    "ReplayOdometry",
    "StereoOdometry",
    "VoParams",
    "VoStep",
    "WindowConfig",
    "planar_step",
    "planar_velocities",
    "read_pose_file",
    "replay_odometry",
    "run_odometry",
]
