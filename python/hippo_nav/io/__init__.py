"""Reading and writing trajectory files (KITTI and TUM formats) and the package's data error."""

from hippo_nav.io.errors import DatasetError, read_text
from hippo_nav.io.poses import (
    matrix_from_quaternion,
    quaternion_from_matrix,
    read_kitti_poses,
    read_tum,
    write_kitti_poses,
    write_tum,
)

__all__ = [
    "DatasetError",
    "matrix_from_quaternion",
    "quaternion_from_matrix",
    "read_kitti_poses",
    "read_text",
    "read_tum",
    "write_kitti_poses",
    "write_tum",
]
