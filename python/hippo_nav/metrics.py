"""Trajectory metrics: ATE RMSE after Umeyama alignment, and the KITTI devkit's relative errors.

All functions take (N, 4, 4) or (N, 3, 4) `world_from_camera` arrays of matching frames (ground truth
first, estimate second), in any memory layout.

ATE (absolute trajectory error). Align the estimated positions to the ground truth with Umeyama's
closed form (1991), minimising Σ‖gᵢ − (s R eᵢ + t)‖²; `align="se3"` fixes s = 1, `"sim3"` fits s,
`"none"` uses the estimate as is. ATE RMSE = sqrt(mean‖gᵢ − (s R eᵢ + t)‖²) in metres. With
`planar=True` both trajectories are first projected onto the ground plane (KITTI: x–z, dropping y,
which points down) and aligned there in 2-D, which is the right measure for a 2-D map. (evo's
`--project_to_plane` aligns in 3-D first and projects afterwards; on a planar estimate the two agree.)

KITTI relative errors (devkit `evaluate_odometry.cpp`). Distances dᵢ are the cumulative ground-truth path
length. For every `step`-th first frame i and every segment length L (100, 200, …, 800 m) take the first
frame j with dⱼ > dᵢ + L (skip if none), the pose error E = (Eᵢ⁻¹Eⱼ)⁻¹ (Gᵢ⁻¹Gⱼ), and record
‖t(E)‖ / L and angle(R(E)) / L (the devkit's arccos((tr R − 1)/2), evaluated stably, see
`rotation_angle_rad`). t_rel is the mean of the former over
all segments in percent; r_rel the mean of the latter in degrees per 100 m. Poses are inverted as
rigid transforms ([Rᵀ | −Rᵀt]), as evo does.

Interpolated ground truth. KITTI's poses come from a GPS/IMU unit; where it dropped out, the released poses
fill the gap with one constant motion: every step turns by the same rotation, to a few thousandths of a
degree. A car never does that (the measured steps of every sequence change by 0.07–0.16° from one to the next, at the median, from
road bumps and steering alone), so such a stretch is not a measurement, and on short segments it dominates
r_rel: KITTI 06 frames 0–11 are one (docs/vo.md, "Ground truth that is not measured", where two
estimates from the images alone and the VO agree with each other and not with it). `interpolated_steps` finds such
stretches; `relative_errors_kitti(..., exclude_steps=...)` leaves out the segments that cross one. Real
data only: a rendered or synthetic drive can turn at a constant rate for real. (A car standing still comes
closest among measured steps: 07's stops would be flagged from a tolerance of 0.01°, five times this one.)
"""

from __future__ import annotations

import numpy as np

from hippo_nav.io.errors import DatasetError

KITTI_SEGMENT_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


def _as_poses(poses: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(poses, dtype=np.float64)
    if array.ndim != 3 or array.shape[1:] not in ((4, 4), (3, 4)):
        raise DatasetError(f"{name} must have shape (N, 4, 4) or (N, 3, 4), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise DatasetError(f"{name} contains NaN or infinity")
    if array.shape[1] == 3:
        bottom = np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(array), 1, 4))
        array = np.concatenate([array, bottom], axis=1)
    return array


def _pair(gt: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gt, est = _as_poses(gt, "ground truth"), _as_poses(est, "estimate")
    if len(gt) != len(est):
        raise DatasetError(
            f"ground truth has {len(gt)} poses, the estimate {len(est)}; pass matching frames "
            "(e.g. gt[dataset.frame_indices])"
        )
    if len(gt) < 2:
        raise DatasetError("need at least 2 poses to compare trajectories")
    return gt, est


def umeyama_alignment(
    source: np.ndarray, target: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) minimising Σ‖targetᵢ − (s R sourceᵢ + t)‖² over rotations R (Umeyama 1991).

    `source` and `target` are (N, d) point sets, d = 2 or 3. Raises when the points are degenerate
    (all equal), where no rotation is determined.
    """
    x = np.asarray(source, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2:
        raise DatasetError(f"point sets must both be (N, d), got {x.shape} and {y.shape}")
    if len(x) == 0 or not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise DatasetError("point sets must hold at least one point, every coordinate finite")
    mean_x, mean_y = x.mean(0), y.mean(0)
    xc, yc = x - mean_x, y - mean_y
    variance_x = float((xc * xc).sum(1).mean())
    if variance_x <= 1e-18:
        raise DatasetError("cannot align: the estimated positions are all the same point")
    covariance = yc.T @ xc / len(x)
    u, d, vt = np.linalg.svd(covariance)
    sign = np.ones(x.shape[1])
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[-1] = -1.0  # the closest proper rotation, not a reflection
    rotation = (u * sign) @ vt
    scale = float((d * sign).sum() / variance_x) if with_scale else 1.0
    translation = mean_y - scale * rotation @ mean_x
    return rotation, translation, scale


def _positions(poses: np.ndarray, planar: bool) -> np.ndarray:
    # KITTI ground plane: x (right) and z (forward); y points down.
    return poses[:, [0, 2], 3] if planar else poses[:, :3, 3]


def ate_errors(gt: np.ndarray, est: np.ndarray, planar: bool = False, align: str = "se3") -> np.ndarray:
    """Per-pose position errors (m) after alignment; see the module doc."""
    gt, est = _pair(gt, est)
    if align not in ("se3", "sim3", "none"):
        raise DatasetError(f"align must be 'se3', 'sim3' or 'none', got {align!r}")
    target, source = _positions(gt, planar), _positions(est, planar)
    if align != "none":
        rotation, translation, scale = umeyama_alignment(source, target, with_scale=align == "sim3")
        source = scale * source @ rotation.T + translation
    return np.linalg.norm(target - source, axis=1)


def ate_rmse(gt: np.ndarray, est: np.ndarray, planar: bool = False, align: str = "se3") -> float:
    """Absolute trajectory error, RMSE in metres (see the module doc for alignment and `planar`)."""
    errors = ate_errors(gt, est, planar=planar, align=align)
    return float(np.sqrt(np.mean(errors * errors)))


def rotation_angle_rad(rotations: np.ndarray) -> np.ndarray:
    """Angle of each 3×3 rotation: atan2(sin θ, cos θ) with cos θ = (tr R − 1)/2, sin θ = ‖vee(R − Rᵀ)‖/2.

    Equal to the devkit's arccos((tr R − 1)/2) for exact rotations, but well conditioned at the small
    angles that odometry errors have: with 7-digit pose files arccos is off by up to ~1e-4 rad there.
    """
    r = np.asarray(rotations)
    cos_angle = 0.5 * (np.trace(r, axis1=-2, axis2=-1) - 1.0)
    skew = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
    )
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), cos_angle)


def rigid_inverse(poses: np.ndarray) -> np.ndarray:
    """[Rᵀ | −Rᵀt] of each pose. Files store R to ~7 digits, so this differs from a general matrix
    inverse by ~1e-7 relative; it is the convention of evo (the devkit inverts in float32, coarser still)."""
    rotation_t = np.swapaxes(poses[..., :3, :3], -1, -2)
    out = np.zeros_like(poses)
    out[..., :3, :3] = rotation_t
    out[..., :3, 3] = -(rotation_t @ poses[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def relative_pose_errors(gt: np.ndarray, est: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For frame pairs (i, j): translation (m) and rotation (rad) of E = (Eᵢ⁻¹Eⱼ)⁻¹ (Gᵢ⁻¹Gⱼ)."""
    gt, est = _pair(gt, est)
    given = np.asarray(pairs)
    if given.size and not (np.issubdtype(given.dtype, np.integer) or np.array_equal(given, np.round(given))):
        raise DatasetError("frame pairs must be whole frame indices (i, j); got fractional values")
    pairs = given.astype(np.int64).reshape(-1, 2)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= len(gt)):
        raise DatasetError(f"frame pairs must index 0..{len(gt) - 1}")
    i, j = pairs[:, 0], pairs[:, 1]
    delta_gt = rigid_inverse(gt[i]) @ gt[j]
    delta_est = rigid_inverse(est[i]) @ est[j]
    error = rigid_inverse(delta_est) @ delta_gt
    return np.linalg.norm(error[:, :3, 3], axis=1), rotation_angle_rad(error[:, :3, :3])


def trajectory_distances_m(poses: np.ndarray) -> np.ndarray:
    """Cumulative path length at each pose (0 at the first)."""
    positions = _as_poses(poses, "poses")[:, :3, 3]
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])


def kitti_segments(gt: np.ndarray, lengths_m=KITTI_SEGMENT_LENGTHS_M, step: int = 10) -> np.ndarray:
    """The devkit's segments as rows (first_frame, last_frame, length_m)."""
    if step < 1:
        raise DatasetError(f"step must be >= 1, got {step}")
    lengths = np.asarray(lengths_m, dtype=np.float64).reshape(-1)
    if not (np.isfinite(lengths).all() and (lengths > 0).all()):
        # A zero length divides by zero (inf t_rel), a negative one gives a negative error.
        raise DatasetError(f"segment lengths must be finite and > 0 m, got {lengths_m!r}")
    distances = trajectory_distances_m(gt)
    rows = []
    for first in range(0, len(distances), step):
        for length in lengths_m:
            # First frame strictly farther than `length` along the path (devkit lastFrameFromSegmentLength).
            last = int(np.searchsorted(distances, distances[first] + length, side="right"))
            if last < len(distances):
                rows.append((first, last, float(length)))
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


# A step whose rotation differs from the next step's by less than this is "constant": measured KITTI steps
# differ by 0.07–0.16° at the median (every sequence 00–10), interpolated ones by at most 0.0018°.
INTERPOLATED_STEP_TOLERANCE_DEG = 0.002
INTERPOLATED_MIN_STEPS = 5  # a shorter run of equal steps can happen by chance on a smooth road


def interpolated_steps(
    gt: np.ndarray,
    tolerance_deg: float = INTERPOLATED_STEP_TOLERANCE_DEG,
    min_steps: int = INTERPOLATED_MIN_STEPS,
) -> np.ndarray:
    """(N − 1,) bool: step k (pose k → k + 1) lies in a run of at least `min_steps` consecutive steps
    that all turn by the same rotation (each within `tolerance_deg` of the next): ground truth filled in
    with a constant motion, not measured (see the module doc)."""
    gt = _as_poses(gt, "ground truth")
    flags = np.zeros(max(len(gt) - 1, 0), dtype=bool)
    if len(gt) < min_steps + 1:
        return flags
    steps = rigid_inverse(gt[:-1]) @ gt[1:]
    change_deg = np.degrees(
        rotation_angle_rad(np.swapaxes(steps[:-1, :3, :3], -1, -2) @ steps[1:, :3, :3])
    )  # change c_k between step k and step k + 1
    same = change_deg < tolerance_deg
    k = 0
    while k < len(same):
        if not same[k]:
            k += 1
            continue
        end = k
        while end < len(same) and same[end]:
            end += 1
        if end - k + 1 >= min_steps:  # changes k..end-1 join steps k..end
            flags[k : end + 1] = True
        k = end
    return flags


def relative_errors_kitti(
    gt: np.ndarray,
    est: np.ndarray,
    lengths=KITTI_SEGMENT_LENGTHS_M,
    step: int = 10,
    exclude_steps: np.ndarray | None = None,
) -> dict:
    """KITTI devkit relative errors (see the module doc).

    Returns `t_rel_percent`, `r_rel_deg_per_100m` (means over all segments), `segments` (their count) and
    `per_length`: {length_m: {"t_rel_percent", "r_rel_deg_per_100m", "segments"}}. With no segment
    (a trajectory shorter than the shortest length) the means are NaN and `segments` is 0.
    `exclude_steps` ((N − 1,) bool, e.g. `interpolated_steps(gt)`): segments that contain a flagged step
    are left out (the devkit's figure is the one without).
    """
    gt, est = _pair(gt, est)
    segments = kitti_segments(gt, lengths, step)
    if exclude_steps is not None:
        flagged = np.asarray(exclude_steps, dtype=bool)
        if flagged.shape != (len(gt) - 1,):
            raise DatasetError(
                f"exclude_steps must have one flag per step ({len(gt) - 1}), got {flagged.shape}"
            )
        crossed = np.concatenate([[0], np.cumsum(flagged)])  # flagged steps before each pose
        first, last = segments[:, 0].astype(np.int64), segments[:, 1].astype(np.int64)
        segments = segments[crossed[last] == crossed[first]]
    if len(segments) == 0:
        nan = float("nan")
        return {"t_rel_percent": nan, "r_rel_deg_per_100m": nan, "segments": 0, "per_length": {}}
    pairs = segments[:, :2].astype(np.int64)
    t_err, r_err = relative_pose_errors(gt, est, pairs)
    t_rel = t_err / segments[:, 2] * 100.0
    r_rel = np.degrees(r_err) / segments[:, 2] * 100.0
    per_length = {}
    for length in lengths:
        mask = segments[:, 2] == float(length)
        if mask.any():
            per_length[float(length)] = {
                "t_rel_percent": float(t_rel[mask].mean()),
                "r_rel_deg_per_100m": float(r_rel[mask].mean()),
                "segments": int(mask.sum()),
            }
    return {
        "t_rel_percent": float(t_rel.mean()),
        "r_rel_deg_per_100m": float(r_rel.mean()),
        "segments": len(segments),
        "per_length": per_length,
    }
