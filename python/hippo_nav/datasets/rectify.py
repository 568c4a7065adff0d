"""Stereo rectification of a calibrated camera pair with OpenCV, for loaders of raw (distorted) images.

Given each camera's intrinsics K_i and distortion D_i and the pose of camera 1 in camera 0
(`camera0_from_camera1`, camera frames x right, y down, z forward), `cv2.stereoRectify` (or
`cv2.fisheye.stereoRectify` for the equidistant model) finds rotations R_i (`rectified_i_from_camera_i`)
that make both image planes parallel to the baseline, and new projections P_i = K'[I | t_i] sharing one
K' (`CALIB_ZERO_DISPARITY`), with P_1[0,3] = −f'·b. `alpha = 0` / `balance = 0` scale K' so every
rectified pixel sees the scene (no black borders, which would make false corners). The remap tables are
computed once (`initUndistortRectifyMap`); each frame costs two `remap`s.

The rectified camera 0 is camera 0 turned by R_0 about its centre, so a pose `world_from_camera0` of the
raw camera becomes `world_from_camera0 @ [R_0ᵀ | 0]` for the rectified one (what ground truth must be).

A rig that cannot become a horizontal pair is an error: cameras at one place, a baseline far from camera
0's x axis (vertical or forward rigs), camera 1 left of camera 0 (swapped), cameras turned far apart.
"""

from __future__ import annotations

import cv2
import numpy as np

from hippo_nav.datasets.base import StereoCalibration, check_calibration, check_intrinsics
from hippo_nav.datasets.common import INTRINSICS_TOLERANCE
from hippo_nav.io.errors import DatasetError

MIN_BASELINE_M = 1e-3
MAX_BASELINE_TILT_DEG = 30.0  # angle between the baseline and camera 0's x axis
MAX_RELATIVE_ROTATION_DEG = 30.0
MAX_ZOOM = 3.0  # rectified focal length / raw focal length (either way)
# CALIB_ZERO_DISPARITY, 0x400 in both cv:: and cv::fisheye:: (OpenCV 5's Python module lacks the fisheye name).
ZERO_DISPARITY = 1024

_PINHOLE_MODELS = {"radial-tangential", "radtan", "plumb_bob", "rational_polynomial", "pinhole", "none", ""}
_FISHEYE_MODELS = {"equidistant", "fisheye", "kannala_brandt", "kannala-brandt"}


def distortion_kind(model: str, where: str) -> str:
    """'pinhole' (OpenCV's radial-tangential/rational model) or 'fisheye' (equidistant) for a model name."""
    name = str(model).strip().lower()
    if name in _PINHOLE_MODELS:
        return "pinhole"
    if name in _FISHEYE_MODELS:
        return "fisheye"
    raise DatasetError(
        f"{where}: distortion model {model!r} is not supported; use radial-tangential (plumb_bob) or "
        "equidistant"
    )


def _intrinsics(
    K: np.ndarray, D: np.ndarray, kind: str, size: tuple[int, int], where: str
) -> tuple[np.ndarray, np.ndarray]:
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(D, dtype=np.float64).reshape(-1)
    if not (np.isfinite(K).all() and np.isfinite(D).all()) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DatasetError(f"{where}: intrinsics need positive finite focal lengths, got K = {K.tolist()}")
    check_intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], size, where)
    if kind == "fisheye":
        if D.size != 4:
            raise DatasetError(
                f"{where}: the equidistant model needs 4 distortion coefficients, got {D.size}"
            )
        return K, D.reshape(4, 1)
    if D.size not in (0, 4, 5, 8, 12, 14):
        raise DatasetError(f"{where}: {D.size} distortion coefficients; radial-tangential takes 4, 5 or 8")
    return K, (D if D.size else np.zeros(4)).reshape(-1, 1)


def check_rig(camera0_from_camera1: np.ndarray, where: str) -> None:
    """Raise when the two cameras cannot be rectified into a horizontal pair with camera 1 on the right."""
    pose = np.asarray(camera0_from_camera1, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise DatasetError(f"{where}: the pose of camera 1 in camera 0 must be a finite 4x4 matrix")
    rotation, centre = pose[:3, :3], pose[:3, 3]
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3 or abs(np.linalg.det(rotation) - 1) > 1e-3:
        raise DatasetError(f"{where}: the relative rotation of the cameras is not a rotation matrix")
    baseline_m = float(np.linalg.norm(centre))
    if baseline_m < MIN_BASELINE_M:
        raise DatasetError(
            f"{where}: the two cameras are at the same place (baseline {baseline_m:.2g} m): not a stereo pair"
        )
    tilt_deg = float(np.degrees(np.arccos(np.clip(abs(centre[0]) / baseline_m, -1.0, 1.0))))
    if tilt_deg > MAX_BASELINE_TILT_DEG:
        raise DatasetError(
            f"{where}: camera 1 is not beside camera 0 (its centre is at {np.round(centre, 4).tolist()} m in "
            f"camera 0, {tilt_deg:.0f}° off the x axis): a vertical or forward rig cannot be rectified into "
            "a left/right pair"
        )
    if centre[0] < 0:
        raise DatasetError(
            f"{where}: camera 1 is left of camera 0 (x = {centre[0]:.4f} m in camera 0); camera 0 must be "
            "the left camera: swap the two cameras"
        )
    angle_deg = float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))))
    if angle_deg > MAX_RELATIVE_ROTATION_DEG:
        raise DatasetError(
            f"{where}: the cameras are turned {angle_deg:.0f}° from each other (more than "
            f"{MAX_RELATIVE_ROTATION_DEG:.0f}°): their views cannot be rectified into one pair"
        )


class StereoRectifier:
    """Rectifies raw stereo pairs: `rectifier(left, right) -> (left, right)` and the rectified rig.

    `calibration` is the rectified pair's (P0, P1, image size); `rectified_from_camera0` the rotation R_0
    (3×3) of camera 0 into its rectified frame."""

    def __init__(
        self,
        maps: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
        calibration: StereoCalibration,
        rectified_from_camera0: np.ndarray,
    ) -> None:
        self.maps = maps
        self.calibration = calibration
        self.rectified_from_camera0 = rectified_from_camera0

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        (l1, l2), (r1, r2) = self.maps
        return (
            cv2.remap(left, l1, l2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
            cv2.remap(right, r1, r2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
        )

    def rectified_pose(self, world_from_camera0: np.ndarray) -> np.ndarray:
        """`world_from_rectified0` of raw camera-0 poses (..., 4, 4)."""
        turn = np.eye(4)
        turn[:3, :3] = self.rectified_from_camera0.T
        return np.asarray(world_from_camera0) @ turn


def check_projections(p0: np.ndarray, p1: np.ndarray, where: str) -> None:
    if not (np.isfinite(p0).all() and np.isfinite(p1).all()):
        raise DatasetError(f"{where}: rectification failed (non-finite projections); check the calibration")
    if p0[0, 0] <= 0 or p0[1, 1] <= 0 or abs(p0[2, 2] - 1) > 1e-9 or np.abs(p0[:, 3]).max() > 1e-9 * p0[0, 0]:
        raise DatasetError(f"{where}: the left projection is not K[I|0]: P = {np.round(p0, 4).tolist()}")
    if np.abs(p0[:, :3] - p1[:, :3]).max() > INTRINSICS_TOLERANCE * max(p0[0, 0], 1.0):
        raise DatasetError(
            f"{where}: the left and right projections have different intrinsics: not a rectified pair"
        )
    if abs(p1[1, 3]) > 1e-6 * abs(p1[0, 3]) or abs(p1[2, 3]) > 1e-9:
        raise DatasetError(f"{where}: the rectified pair is not horizontal (P1 = {np.round(p1, 4).tolist()})")
    if p1[0, 3] >= 0:
        raise DatasetError(
            f"{where}: P1[0,3] = {p1[0, 3]:.4g} must be negative (right camera at +baseline along x); "
            "is camera 0 the left camera?"
        )


def rectify_rig(
    K0: np.ndarray,
    D0: np.ndarray,
    K1: np.ndarray,
    D1: np.ndarray,
    camera0_from_camera1: np.ndarray,
    image_size_px: tuple[int, int],
    model: str,
    where: str,
) -> StereoRectifier:
    """Rectify a calibrated pair (see the module doc); `where` names the calibration in errors."""
    kind = distortion_kind(model, where)
    size = (int(image_size_px[0]), int(image_size_px[1]))
    K0, D0 = _intrinsics(K0, D0, kind, size, where)
    K1, D1 = _intrinsics(K1, D1, kind, size, where)
    check_rig(camera0_from_camera1, where)
    camera1_from_camera0 = np.linalg.inv(camera0_from_camera1)
    # OpenCV's fisheye functions need contiguous arrays; slices of a 4×4 are not.
    R = np.ascontiguousarray(camera1_from_camera0[:3, :3])
    T = np.ascontiguousarray(camera1_from_camera0[:3, 3]).reshape(3, 1)
    try:
        if kind == "fisheye":
            R0, R1, P0, P1, _ = cv2.fisheye.stereoRectify(
                K0, D0, K1, D1, size, R, T, ZERO_DISPARITY, newImageSize=size, balance=0.0
            )
        else:
            R0, R1, P0, P1, *_ = cv2.stereoRectify(
                K0, D0, K1, D1, size, R, T, flags=ZERO_DISPARITY, alpha=0.0
            )
    except cv2.error as err:
        raise DatasetError(
            f"{where}: OpenCV cannot rectify this rig ({str(err).strip().splitlines()[-1]})"
        ) from None
    check_projections(P0, P1, where)
    zoom = P0[0, 0] / K0[0, 0]
    if not 1 / MAX_ZOOM <= zoom <= MAX_ZOOM:
        raise DatasetError(
            f"{where}: rectification would scale the images by {zoom:.2f} (focal {K0[0, 0]:.1f} -> "
            f"{P0[0, 0]:.1f} px); the distortion or the relative pose is implausible"
        )
    calibration = check_calibration(StereoCalibration(P0.copy(), P1.copy(), None, None, size), where)
    return StereoRectifier(
        (_maps(K0, D0, R0, P0, size, kind), _maps(K1, D1, R1, P1, size, kind)), calibration, R0.copy()
    )


def rectifier_from_projections(
    cameras: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], ...],
    image_size_px: tuple[int, int],
    model: str,
    where: str,
) -> StereoRectifier:
    """A rectifier from a recorded stereo calibration: per camera (K, D, R, P), as in ROS CameraInfo."""
    kind = distortion_kind(model, where)
    size = (int(image_size_px[0]), int(image_size_px[1]))
    prepared = []
    for K, D, R, P in cameras:
        K, D = _intrinsics(K, D, kind, size, where)
        R = np.asarray(R, dtype=np.float64).reshape(3, 3)
        P = np.asarray(P, dtype=np.float64).reshape(3, 4)
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3:
            raise DatasetError(
                f"{where}: the rectification matrix R is not a rotation: {np.round(R, 4).tolist()}"
            )
        prepared.append((K, D, R, P))
    (K0, D0, R0, P0), (K1, D1, R1, P1) = prepared
    check_projections(P0, P1, where)
    calibration = check_calibration(StereoCalibration(P0.copy(), P1.copy(), None, None, size), where)
    return StereoRectifier(
        (_maps(K0, D0, R0, P0, size, kind), _maps(K1, D1, R1, P1, size, kind)), calibration, R0.copy()
    )


def _maps(
    K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray, size: tuple[int, int], kind: str
) -> tuple[np.ndarray, np.ndarray]:
    if kind == "fisheye":
        return cv2.fisheye.initUndistortRectifyMap(K, D, R, P[:, :3], size, cv2.CV_16SC2)
    return cv2.initUndistortRectifyMap(K, D, R, P[:, :3], size, cv2.CV_16SC2)
