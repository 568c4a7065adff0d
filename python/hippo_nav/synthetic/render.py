"""Render a stereo sequence along a trajectory and write it in the KITTI odometry layout.

Rig: a rectified pair with K = [[f, 0, cx], [0, f, cy], [0, 0, 1]], f = `focal_ratio` · width
(KITTI's ratio by default: 718.856 / 1241), principal point at the image centre ((W−1)/2, (H−1)/2),
the right camera `baseline_m` along camera-0 +x. calib.txt holds P0 = K[I|0], P1 = K[I | (−b, 0, 0)]
(so P1[0,3] = −f·b), and P2 = P0, P3 = P1 (the synthetic rig has no colour cameras). times.txt is
i / `frame_rate_hz`; poses/XX.txt the given `world_from_camera` of camera 0.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from hippo_nav.io.errors import DatasetError
from hippo_nav.io.poses import write_kitti_poses
from hippo_nav.synthetic.world import StreetWorld

KITTI_FOCAL_RATIO = 718.856 / 1241.0


def stereo_projections(
    image_size_px: tuple[int, int], baseline_m: float, focal_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """(P0, P1) of the synthetic rectified rig."""
    width, height = image_size_px
    focal_px = focal_ratio * width
    K = np.array([[focal_px, 0.0, (width - 1) / 2], [0.0, focal_px, (height - 1) / 2], [0.0, 0.0, 1.0]])
    p0 = np.hstack([K, np.zeros((3, 1))])
    p1 = p0.copy()
    p1[0, 3] = -focal_px * baseline_m
    return p0, p1


def _write_calibration(path: Path, p0: np.ndarray, p1: np.ndarray) -> None:
    lines = [
        f"{name}: " + " ".join(f"{x:.12e}" for x in p.ravel())
        for name, p in (("P0", p0), ("P1", p1), ("P2", p0), ("P3", p1))
    ]
    path.write_text("\n".join(lines) + "\n")


def render_sequence(
    world_from_camera: np.ndarray,
    out_root: str | Path,
    sequence: str = "00",
    image_size_px: tuple[int, int] = (320, 96),
    baseline_m: float = 0.537,
    seed: int = 0,
    *,
    frame_rate_hz: float = 10.0,
    focal_ratio: float = KITTI_FOCAL_RATIO,
    street_half_width_m: float = 7.0,
    camera_height_m: float = 1.65,
    noise_std: float = 0.0,
    workers: int = 2,
    progress: bool = False,
) -> Path:
    """Render the stereo pair at every pose and write a KITTI-layout sequence under `out_root`; returns it.

    `noise_std` adds seeded Gaussian sensor noise (gray levels) independently to each image.
    Frames are written as they are rendered, so an interrupted run leaves the finished frames on disk.
    `workers` threads render frames in parallel (NumPy releases the GIL in its array loops); the output
    does not depend on it.
    """
    poses = np.asarray(world_from_camera, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] not in ((4, 4), (3, 4)) or len(poses) == 0:
        raise DatasetError(f"world_from_camera must have shape (N, 4, 4), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise DatasetError("world_from_camera holds NaN or infinity")
    if poses.shape[1] == 3:
        poses = np.concatenate([poses, np.tile([[[0.0, 0.0, 0.0, 1.0]]], (len(poses), 1, 1))], axis=1)
    width, height = (int(x) for x in image_size_px)
    if width < 16 or height < 16 or baseline_m <= 0 or frame_rate_hz <= 0:
        raise DatasetError("image size must be at least 16x16 px, baseline and frame rate positive")

    p0, p1 = stereo_projections((width, height), baseline_m, focal_ratio)
    K = p0[:, :3]
    world = StreetWorld(
        poses[:, :3, 3], street_half_width_m=street_half_width_m, camera_height_m=camera_height_m, seed=seed
    )
    root = Path(out_root)
    sequence_dir = root / "sequences" / sequence
    for camera in ("image_0", "image_1"):
        (sequence_dir / camera).mkdir(parents=True, exist_ok=True)
    _write_calibration(sequence_dir / "calib.txt", p0, p1)
    np.savetxt(sequence_dir / "times.txt", np.arange(len(poses)) / frame_rate_hz, fmt="%.6e")
    write_kitti_poses(root / "poses" / f"{sequence}.txt", poses)

    right_from_left = np.eye(4)
    right_from_left[0, 3] = baseline_m  # right camera centre, in camera-0 coordinates

    def render_frame(i: int) -> None:
        # Noise is seeded per frame so the images do not depend on the order threads finish in.
        noise_rng = np.random.default_rng([seed, i])
        for camera, pose in (("image_0", poses[i]), ("image_1", poses[i] @ right_from_left)):
            image = world.render(pose, K, (width, height))
            if noise_std > 0:
                noisy = image + noise_rng.normal(0.0, noise_std, image.shape)
                image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
            if not cv2.imwrite(str(sequence_dir / camera / f"{i:06d}.png"), image):
                raise DatasetError(f"{sequence_dir / camera}: cannot write images there")

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(poses), desc=f"rendering {sequence}", unit="frame")
    with ThreadPoolExecutor(max_workers=max(int(workers), 1)) as pool:
        for _ in pool.map(render_frame, range(len(poses))):
            if bar is not None:
                bar.update()
    if bar is not None:
        bar.close()
    return root


def rendered_params(root: Path, sequence: str) -> dict | None:
    """The parameters stamp written by `render_cached`, or None."""
    stamp = root / "sequences" / sequence / "render.json"
    try:
        return json.loads(stamp.read_text())
    except (OSError, ValueError):
        return None


def render_cached(world_from_camera: np.ndarray, out_root: str | Path, sequence: str = "00", **kw) -> Path:
    """`render_sequence` unless `out_root` already holds this exact rendering (same poses and settings)."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    root = Path(out_root)
    settings = {
        k: list(v) if isinstance(v, tuple) else v for k, v in kw.items() if k not in ("progress", "workers")
    }
    params = {"poses_sha": _digest(poses), **settings}
    image_dirs = [root / "sequences" / sequence / cam for cam in ("image_0", "image_1")]
    complete = all(d.is_dir() and len(list(d.glob("*.png"))) == len(poses) for d in image_dirs)
    if complete and rendered_params(root, sequence) == params:
        return root
    render_sequence(poses, root, sequence, **kw)
    (root / "sequences" / sequence / "render.json").write_text(json.dumps(params, sort_keys=True))
    return root


def _digest(array: np.ndarray) -> str:
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(np.round(array, 9)).tobytes()).hexdigest()[:16]
