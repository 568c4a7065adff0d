"""Render a stereo sequence along a trajectory and write it in the KITTI odometry layout.

Rig: a rectified pair with K = [[f, 0, cx], [0, f, cy], [0, 0, 1]], f = `focal_ratio` · width
(KITTI's ratio by default: 718.856 / 1241), principal point at the image centre ((W−1)/2, (H−1)/2),
the right camera `baseline_m` along camera-0 +x. calib.txt holds P0 = K[I|0], P1 = K[I | (−b, 0, 0)]
(so P1[0,3] = −f·b), and P2 = P0, P3 = P1 (the synthetic rig has no colour cameras). times.txt is
i / `frame_rate_hz`; poses/XX.txt the given `world_from_camera` of camera 0.

`appearance` ("same", "mild", "strong"; `synthetic/appearance.py`, docs/render.md) makes a place look different
on each pass: light, shadows, shop fronts and posters, parked cars, noise, blur, vignetting, and in
`render_kitti` another lane. "same" renders exactly what this module always rendered.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from hippo_nav.datasets.common import image_size_in_header, read_image_file
from hippo_nav.io.atomic import open_atomic, write_image, write_text
from hippo_nav.io.errors import DatasetError
from hippo_nav.io.poses import write_kitti_poses
from hippo_nav.synthetic.appearance import (
    AppearanceModel,
    FrameAppearance,
    appearance_level,
    lane_offsets_m,
    pass_indices,
    shift_sideways,
    shutter_motion,
    smoothed_passes,
)
from hippo_nav.synthetic.world import StreetWorld

KITTI_FOCAL_RATIO = 718.856 / 1241.0
MAX_SIDE_PX = 4096
"""Largest image side a render accepts (KITTI's images are 1241 px wide; 4096² is 16 MB a frame)."""


def check_sequence_name(sequence: str) -> str:
    """The sequence, when it is a plain name (letters, digits, `_`, `-`, `.`; not `.` or `..`): it becomes a
    folder and a file name under the output root, so a path (`../x`, `a/b`) would write outside it."""
    name = str(sequence)
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", name) or name.strip(".") == "":
        raise DatasetError(
            f"sequence {name!r} must be a name (letters, digits, '_', '-', '.'; e.g. 00), not a path"
        )
    return name


MAX_RENDER_SEED = 2**63 - 1
"""Largest texture seed: NumPy's seed sequences take any non-negative integer; a bigger one is a typo, and
would not be one integer in the render stamp's JSON for every reader."""
MAX_RENDER_WORKERS = 4096
"""Most rendering threads (more than any machine has cores; each holds a frame's buffers)."""


def check_render_options(seed: object, workers: object, poles: object) -> tuple[int, int, bool]:
    """(seed, workers, poles) when the seed is an integer from 0 to `MAX_RENDER_SEED`, the workers from 0
    (taken as 1, as always) to `MAX_RENDER_WORKERS` and poles a boolean; a `DatasetError` saying which and
    what to give otherwise (a negative seed was a NumPy traceback, after the stamp was written)."""
    import numbers

    def integer(value: object, what: str, low: int, high: int, give: str) -> int:
        if (
            isinstance(value, bool)
            or not isinstance(value, numbers.Integral)
            or not low <= int(value) <= high
        ):
            raise DatasetError(f"{what} {value!r}: give {give}")
        return int(value)

    seed = integer(seed, "seed", 0, MAX_RENDER_SEED, f"an integer from 0 to {MAX_RENDER_SEED}")
    workers = integer(
        workers, "workers", 0, MAX_RENDER_WORKERS, f"a number of threads from 1 to {MAX_RENDER_WORKERS}"
    )
    if not isinstance(poles, (bool, np.bool_)):
        raise DatasetError(f"poles {poles!r}: give True or False")
    return seed, workers, bool(poles)


def check_image_size(image_size_px: tuple[int, int]) -> tuple[int, int]:
    """(width, height) when each side is 16 to `MAX_SIDE_PX` pixels."""
    width, height = (int(x) for x in image_size_px)
    if not (16 <= width <= MAX_SIDE_PX and 16 <= height <= MAX_SIDE_PX):
        raise DatasetError(
            f"image size {width}x{height}: each side must be 16 to {MAX_SIDE_PX} px (KITTI's is 1241x376)"
        )
    return width, height


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
    write_text(path, "\n".join(lines) + "\n")


def render_sequence(
    world_from_camera: np.ndarray,
    out_root: str | Path,
    sequence: str = "00",
    image_size_px: tuple[int, int] = (320, 96),
    baseline_m: float = 0.537,
    seed: int = 0,
    *,
    frame_rate_hz: float = 10.0,
    timestamps_s: np.ndarray | None = None,
    frames: np.ndarray | None = None,
    keep_existing: bool = False,
    focal_ratio: float = KITTI_FOCAL_RATIO,
    street_half_width_m: float = 7.0,
    camera_height_m: float = 1.65,
    noise_std: float = 0.0,
    appearance: str = "same",
    street_path_m: np.ndarray | None = None,
    passes: np.ndarray | None = None,
    poles: bool = False,
    workers: int = 2,
    progress: bool = False,
) -> Path:
    """Render the stereo pair at every pose and write a KITTI-layout sequence under `out_root`; returns it.

    The world is built from the whole trajectory; `frames` (indices into it) limits which frames are
    rendered, while times.txt and the pose file always cover every pose, so a partial render is a KITTI
    sequence whose images stop early. `timestamps_s` (one per pose) replaces `i / frame_rate_hz`.
    `noise_std` adds seeded Gaussian sensor noise (gray levels) independently to each image.
    Each image is written to a temporary name and renamed, so an interrupted render leaves only complete
    frames; with `keep_existing` frames whose two images exist are not rendered again (resuming).
    `workers` threads render frames in parallel (NumPy releases the GIL in its array loops); the output
    does not depend on it.

    `appearance` ("same", "mild" or "strong") changes the look of a place from one pass to the next
    (`hippo_nav.synthetic.appearance`); the pass of each frame is `pass_indices` of the camera positions unless
    `passes` (one per pose) gives it. The street follows the camera path unless `street_path_m` (M, 3) gives
    the path it is built along (e.g. the first pass of a street driven again in another lane). `poles` puts
    posts on the pavements (`StreetWorld`: trees, lamp posts and signs, the structure a street has along its
    length besides its walls; docs/render.md).
    """
    # Every argument is checked before anything is written, in this order (the first fault is the one named).
    poses = _checked_world_from_camera(world_from_camera)
    sequence = check_sequence_name(sequence)
    width, height = check_image_size(image_size_px)
    if not (baseline_m > 0 and frame_rate_hz > 0):
        raise DatasetError(f"baseline ({baseline_m} m) and frame rate ({frame_rate_hz} Hz) must be positive")
    timestamps_s = _checked_timestamps_s(timestamps_s, len(poses), frame_rate_hz)
    selected = _checked_frames(frames, len(poses))
    appearance_level(appearance)  # an unknown level fails here, before anything is written
    street = _checked_street_path_m(street_path_m, poses)

    # The rig, the street and its appearance (the model checks `passes`, still before any write).
    p0, p1 = stereo_projections((width, height), baseline_m, focal_ratio)
    world = StreetWorld(
        street,
        street_half_width_m=street_half_width_m,
        camera_height_m=camera_height_m,
        seed=seed,
        poles=poles,
    )
    model = None if appearance == "same" else AppearanceModel(world, appearance, seed, poses, passes)

    # The sequence's text files cover every pose; the images follow, frame by frame.
    root = Path(out_root)
    sequence_dir = _write_sequence_files(root, sequence, p0, p1, timestamps_s, poses)
    write_frame = _StereoFrameWriter(
        world, model, poses, p0[:, :3], (width, height), baseline_m, seed, noise_std, sequence_dir
    )
    todo = [
        int(i)
        for i in selected
        if not (keep_existing and _frame_on_disk(sequence_dir, int(i), (width, height)))
    ]
    _render_frames(write_frame, todo, len(selected), f"rendering {sequence}", workers, progress)
    return root


def _checked_world_from_camera(world_from_camera: np.ndarray) -> np.ndarray:
    """The poses as (N, 4, 4) float64: finite, at least one; (N, 3, 4) rows get their [0, 0, 0, 1]."""
    poses = np.asarray(world_from_camera, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] not in ((4, 4), (3, 4)) or len(poses) == 0:
        raise DatasetError(f"world_from_camera must have shape (N, 4, 4), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise DatasetError("world_from_camera holds NaN or infinity")
    if poses.shape[1] == 3:
        poses = np.concatenate([poses, np.tile([[[0.0, 0.0, 0.0, 1.0]]], (len(poses), 1, 1))], axis=1)
    return poses


def _checked_timestamps_s(timestamps_s: np.ndarray | None, n_poses: int, frame_rate_hz: float) -> np.ndarray:
    """One finite time (s) per pose: the given ones, else i / `frame_rate_hz`."""
    if timestamps_s is None:
        timestamps_s = np.arange(n_poses) / frame_rate_hz
    timestamps_s = np.asarray(timestamps_s, dtype=np.float64).reshape(-1)
    if len(timestamps_s) != n_poses or not np.all(np.isfinite(timestamps_s)):
        raise DatasetError(f"need one finite timestamp per pose: {len(timestamps_s)} for {n_poses} poses")
    return timestamps_s


def _checked_frames(frames: np.ndarray | None, n_poses: int) -> np.ndarray:
    """The frame indices to render (every pose by default), each in [0, `n_poses`)."""
    selected = np.arange(n_poses) if frames is None else np.asarray(frames, dtype=np.int64).reshape(-1)
    if selected.size and (selected.min() < 0 or selected.max() >= n_poses):
        raise DatasetError(f"frames to render must lie in [0, {n_poses})")
    return selected


def _checked_street_path_m(street_path_m: np.ndarray | None, world_from_camera: np.ndarray) -> np.ndarray:
    """The (M, 3) path (world frame, m) the street is built along: the camera centres unless given."""
    street = (
        world_from_camera[:, :3, 3] if street_path_m is None else np.asarray(street_path_m, dtype=np.float64)
    )
    if street.ndim != 2 or street.shape[1] != 3:
        raise DatasetError(f"street_path_m must have shape (M, 3), got {street.shape}")
    return street


def _write_sequence_files(
    root: Path,
    sequence: str,
    p0: np.ndarray,
    p1: np.ndarray,
    timestamps_s: np.ndarray,
    world_from_camera: np.ndarray,
) -> Path:
    """The image folders, calib.txt, times.txt and poses/<sequence>.txt of a KITTI sequence; returns its
    folder (`root/sequences/<sequence>`)."""
    sequence_dir = root / "sequences" / sequence
    for camera in ("image_0", "image_1"):
        (sequence_dir / camera).mkdir(parents=True, exist_ok=True)
    _write_calibration(sequence_dir / "calib.txt", p0, p1)
    with open_atomic(sequence_dir / "times.txt", "wb") as f:
        np.savetxt(f, timestamps_s, fmt="%.6e")
    write_kitti_poses(root / "poses" / f"{sequence}.txt", world_from_camera)
    return sequence_dir


_PNG_END = b"IEND\xaeB`\x82"  # the last chunk of every PNG file, with its checksum


def _frame_on_disk(sequence_dir: Path, i: int, size_px: tuple[int, int]) -> bool:
    """Both images of frame `i` are whole PNGs of this render's size. The render writes them atomically,
    but a file emptied or cut short since (a full disk, a copy that stopped) is rendered again, not kept."""
    for camera in ("image_0", "image_1"):
        path = sequence_dir / camera / f"{i:06d}.png"
        try:
            data = path.read_bytes() if path.is_file() else b""
        except OSError:
            return False
        if image_size_in_header(data) != size_px or not data.endswith(_PNG_END):
            return False
    return True


class _StereoFrameWriter:
    """Renders frame i's stereo pair and writes image_0/ and image_1/`{i:06d}.png` (one call per frame, from
    any thread: every random draw is seeded by the frame, so the images do not depend on the order)."""

    def __init__(
        self,
        world: StreetWorld,
        model: AppearanceModel | None,
        world_from_camera: np.ndarray,
        K: np.ndarray,
        image_size_px: tuple[int, int],
        baseline_m: float,
        seed: int,
        noise_std: float,
        sequence_dir: Path,
    ) -> None:
        self.world, self.model = world, model
        self.world_from_camera, self.K, self.image_size_px = world_from_camera, K, image_size_px
        self.seed, self.noise_std, self.sequence_dir = seed, noise_std, sequence_dir
        self.right_from_left = np.eye(4)
        self.right_from_left[0, 3] = baseline_m  # right camera centre, in camera-0 coordinates

    def __call__(self, i: int) -> None:
        # Noise is seeded per frame so the images do not depend on the order threads finish in.
        noise_rng = np.random.default_rng([self.seed, i])
        look = None if self.model is None else self.model.frame(i)
        # The appearance's own sensor noise, a stream apart from noise_std's.
        sensor_rng = np.random.default_rng([self.seed, i, 0xA99])
        left = self.world_from_camera[i]
        for camera, pose in (("image_0", left), ("image_1", left @ self.right_from_left)):
            image = self._render(i, pose, look, sensor_rng)
            if self.noise_std > 0:
                noisy = image + noise_rng.normal(0.0, self.noise_std, image.shape)
                image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
            # Atomic (a fresh exclusive temporary, renamed): a frame on disk is a complete frame, and a
            # link planted in the folder is replaced, never written through.
            write_image(self.sequence_dir / camera / f"{i:06d}.png", image)

    def _render(
        self,
        i: int,
        world_from_camera: np.ndarray,
        look: FrameAppearance | None,
        sensor_rng: np.random.Generator,
    ) -> np.ndarray:
        """One camera's (H, W) uint8 image of frame `i`, before `noise_std`'s noise."""
        if self.model is None or look is None:  # "same": the street as it always was
            return self.world.render(world_from_camera, self.K, self.image_size_px)
        motion = shutter_motion(self.world_from_camera, i)
        if motion is not None:  # the rig's motion seen from the right camera, as used so far for both cameras
            motion = np.linalg.inv(self.right_from_left) @ motion @ self.right_from_left
        return self.model.render(
            world_from_camera, self.K, self.image_size_px, look, camera_from_next=motion, noise_rng=sensor_rng
        )


def _render_frames(
    write_frame: Callable[[int], None],
    todo: list[int],
    n_selected: int,
    description: str,
    workers: int,
    progress: bool,
) -> None:
    """`write_frame` of every frame in `todo` on `workers` threads, with a progress bar over the
    `n_selected` frames asked for (those already on disk count as done)."""
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_selected, initial=n_selected - len(todo), desc=description,
                   unit="frame", dynamic_ncols=True)  # fmt: skip
    pool = ThreadPoolExecutor(max_workers=max(int(workers), 1))
    try:
        for _ in pool.map(write_frame, todo):
            if bar is not None:
                bar.update()
    finally:
        # On Ctrl-C, drop the frames not yet started instead of rendering the whole queue first.
        pool.shutdown(wait=True, cancel_futures=True)
        if bar is not None:
            bar.close()


def street_views(
    seeds: tuple[int, ...] = (1, 2, 3, 4),
    frames_per_street: int = 40,
    image_size_px: tuple[int, int] = (640, 192),
) -> Iterator[np.ndarray]:
    """Gray left-camera images of procedural streets, one street per seed, a loop driven through each at
    3 m per frame (nothing is written). The defaults are the images the shipped word vocabulary was trained
    on (`hippo-nav vocabulary`, docs/views.md): streets of other shapes and sizes per seed, rectangles from
    60 × 30 m to 150 × 90 m, at a KITTI-like image size."""
    from hippo_nav.synthetic.trajectories import loop_trajectory

    p0, _ = stereo_projections(image_size_px, 0.537, KITTI_FOCAL_RATIO)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        sides = (float(rng.uniform(60, 150)), float(rng.uniform(30, 90)))
        poses = loop_trajectory(frames_per_street, side_lengths_m=sides, speed_m_per_frame=3.0)
        world = StreetWorld(poses[:, :3, 3], seed=seed)
        for pose in poses:
            yield world.render(pose, p0[:, :3], image_size_px)


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
    # appearance="same" is today's rendering: its stamp stays the one written before appearances existed.
    settings = {
        k: list(v) if isinstance(v, tuple) else _digest(v) if isinstance(v, np.ndarray) else v
        for k, v in kw.items()
        if k not in ("progress", "workers") and not (k == "appearance" and v == "same")
    }
    params = {"poses_sha": _digest(poses), **settings}
    image_dirs = [root / "sequences" / sequence / cam for cam in ("image_0", "image_1")]
    complete = all(d.is_dir() and len(list(d.glob("[0-9]*.png"))) == len(poses) for d in image_dirs)
    if complete and rendered_params(root, sequence) == params and _all_readable(image_dirs):
        return root
    render_sequence(poses, root, sequence, **kw)
    write_text(root / "sequences" / sequence / "render.json", json.dumps(params, sort_keys=True))
    return root


def _all_readable(image_dirs: list[Path]) -> bool:
    """Every cached image decodes: a truncated or corrupted file makes the cache be rendered again
    instead of failing every later run."""
    for directory in image_dirs:
        for path in directory.glob("[0-9]*.png"):
            try:
                read_image_file(path)
            except DatasetError:
                return False
    return True


def _digest(array: np.ndarray) -> str:
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(np.round(array, 9)).tobytes()).hexdigest()[:16]


def render_kitti(
    kitti_root: str | Path,
    sequence: str,
    out_root: str | Path,
    start: int | None = None,
    stop: int | None = None,
    *,
    image_size_px: tuple[int, int] = (320, 96),
    road_smoothing_m: float = 6.0,
    seed: int = 0,
    appearance: str = "same",
    poles: bool = False,
    workers: int = 2,
    progress: bool = False,
) -> Path:
    """Render the synthetic street along a KITTI ground truth into a KITTI root at `out_root`; returns it.

    Reads `kitti_root/poses/NN.txt` and `kitti_root/sequences/NN/times.txt` (no images needed). The camera
    follows the ground truth's horizontal path and heading, level, at a fixed height above a road whose
    height depends on the position only (`road_trajectory`), so every pass sees a street the same way; the
    written `poses/NN.txt` is the exact pose of every rendered camera and times.txt is the original one.
    `start`/`stop` render part of the sequence (frame numbers keep their place). Resumable: a render
    stamp (`render.json`) records the settings, and frames already on disk are kept when they match;
    an `out_root` holding a render with other settings is an error, so nothing is overwritten by mistake.

    `appearance` "mild" or "strong" (recorded in the stamp) changes a place's look on every pass
    (docs/render.md) and drives later passes in another lane: the camera moves sideways (along its x axis) by
    `lane_offsets_m` of the road path's smoothed pass, over ~40 m of road; the street stays where the road
    is, and the written poses are those of the cameras rendered, offsets included. `poles` (recorded in the
    stamp) puts posts on the pavements (`render_sequence`).
    """
    from hippo_nav.synthetic.trajectories import road_trajectory

    # Everything that can refuse the command is checked before the first write: a refused render must not
    # leave a stamp that blocks the corrected command.
    sequence = check_sequence_name(sequence)
    image_size_px = check_image_size(image_size_px)
    seed, workers, poles = check_render_options(seed, workers, poles)
    kitti_root = Path(kitti_root)
    ground_truth, times_s = _read_kitti_ground_truth(kitti_root, sequence)
    lo, hi = _checked_frame_range(start, stop, len(ground_truth))
    appearance_level(appearance)  # an unknown level fails here, before anything is written
    road = road_trajectory(ground_truth, road_smoothing_m)
    world_from_camera, passes = _lane_poses(road, appearance, seed)
    root = Path(out_root)
    stamp = _render_stamp(ground_truth, image_size_px, road_smoothing_m, seed, appearance, poles)
    _check_render_root(root, kitti_root, sequence, stamp)

    # The stamp goes first: an interrupted render resumes only with the same settings.
    sequence_dir = root / "sequences" / sequence
    sequence_dir.mkdir(parents=True, exist_ok=True)
    write_text(sequence_dir / "render.json", json.dumps(stamp, sort_keys=True))
    return render_sequence(
        world_from_camera,
        root,
        sequence,
        image_size_px,
        seed=seed,
        timestamps_s=times_s,
        frames=np.arange(lo, hi),
        keep_existing=True,
        appearance=appearance,
        street_path_m=None if appearance == "same" else road[:, :3, 3],
        passes=passes,
        poles=poles,
        workers=workers,
        progress=progress,
    )


def _read_kitti_ground_truth(kitti_root: Path, sequence: str) -> tuple[np.ndarray, np.ndarray]:
    """(world_from_camera (N, 4, 4), times s (N)) of a KITTI sequence: poses/NN.txt and its times.txt, which
    must list as many frames."""
    from hippo_nav.datasets.kitti import read_times
    from hippo_nav.io.poses import read_kitti_poses

    pose_path = kitti_root / "poses" / f"{sequence}.txt"
    times_path = kitti_root / "sequences" / sequence / "times.txt"
    if not pose_path.is_file():
        raise DatasetError(f"{pose_path}: ground truth not found; rendering follows a KITTI pose file")
    ground_truth = read_kitti_poses(pose_path)
    times = read_times(times_path)
    if len(times) != len(ground_truth):
        raise DatasetError(
            f"{times_path} lists {len(times)} frames but {pose_path} holds {len(ground_truth)} poses; "
            "they must describe the same sequence"
        )
    return ground_truth, times


def _checked_frame_range(start: int | None, stop: int | None, n_frames: int) -> tuple[int, int]:
    """[lo, hi): `start`/`stop` (None: the first / past the last frame), non-empty and within the frames."""
    lo = 0 if start is None else int(start)
    hi = n_frames if stop is None else int(stop)
    if not 0 <= lo < hi <= n_frames:
        raise DatasetError(f"frame range [{lo}, {hi}) is empty or outside the {n_frames} frames")
    return lo, hi


def _lane_poses(
    road_world_from_camera: np.ndarray, appearance: str, seed: int
) -> tuple[np.ndarray, np.ndarray | None]:
    """(world_from_camera, passes) of the cameras to render: the road poses at "same" (passes left to
    `render_sequence`), else each shifted sideways into its pass's lane, with the road's pass indices."""
    if appearance == "same":
        return road_world_from_camera, None
    # Passes follow the road, not the lanes: the street is driven again whichever lane the camera takes.
    road_m = road_world_from_camera[:, :3, 3]
    passes = pass_indices(road_m)
    offsets_m = lane_offsets_m(smoothed_passes(road_m, passes), appearance, seed)
    return shift_sideways(road_world_from_camera, offsets_m), passes


def _render_stamp(
    ground_truth: np.ndarray,
    image_size_px: tuple[int, int],
    road_smoothing_m: float,
    seed: int,
    appearance: str,
    poles: bool,
) -> dict[str, object]:
    """The settings recorded in render.json: a resumed render must have the same."""
    stamp: dict[str, object] = {
        "source_poses_sha": _digest(ground_truth),
        "image_size_px": [int(v) for v in image_size_px],
        "road_smoothing_m": float(road_smoothing_m),
        "seed": int(seed),
    }
    if appearance != "same":  # a "same" stamp is the one written before appearances existed
        stamp["appearance"] = appearance
    if poles:  # likewise, a street without posts keeps its old stamp
        stamp["poles"] = True
    return stamp


def _check_render_root(root: Path, kitti_root: Path, sequence: str, stamp: dict[str, object]) -> None:
    """Refuse an output root whose sequence rendering would overwrite: the KITTI root itself, a sequence
    `hippo-nav render` did not write, or a render with other settings."""
    if root.resolve() == kitti_root.resolve():
        raise DatasetError(
            f"--out {root} is the KITTI root being read: rendering there would overwrite its poses/{sequence}.txt "
            "and calib.txt with the synthetic rig's; choose another folder"
        )
    existing = rendered_params(root, sequence)
    sequence_dir = root / "sequences" / sequence
    foreign = [root / "poses" / f"{sequence}.txt", sequence_dir / "calib.txt", sequence_dir / "times.txt"]
    if existing is None and any(path.exists() or path.is_symlink() for path in foreign):
        raise DatasetError(
            f"{root}: already holds sequence {sequence} that `hippo-nav render` did not write (no render.json "
            "beside its images); choose another --out"
        )
    if existing is not None and existing != stamp:
        raise DatasetError(
            f"{root / 'sequences' / sequence}: holds a render with other settings ({existing}); "
            "choose another --out or delete that folder"
        )
