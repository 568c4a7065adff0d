"""Synthetic stereo sequences: trajectories, exact geometry, revisits, KITTI layout round trip, the demo."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.datasets import DatasetError, KittiOdometry
from hippo_nav.synthetic import (
    DEMO_FRAMES,
    KITTI_FOCAL_RATIO,
    StreetWorld,
    demo_sequence,
    kitti_trajectory,
    level_trajectory,
    loop_trajectory,
    path_length_m,
    planar_poses,
    render_sequence,
    scale_trajectory,
    stereo_projections,
)

SIZE = (320, 96)
BASELINE_M = 0.537


@pytest.fixture(scope="module")
def loop() -> np.ndarray:
    return loop_trajectory(200)


@pytest.fixture(scope="module")
def world(loop: np.ndarray) -> StreetWorld:
    return StreetWorld(loop[:, :3, 3], seed=0)


@pytest.fixture(scope="module")
def intrinsics() -> np.ndarray:
    return stereo_projections(SIZE, BASELINE_M, KITTI_FOCAL_RATIO)[0][:, :3]


def right_pose(left: np.ndarray) -> np.ndarray:
    pose = left.copy()
    pose[:3, 3] += left[:3, :3] @ [BASELINE_M, 0.0, 0.0]
    return pose


def true_depth_m(world: StreetWorld, pose: np.ndarray, K: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    rays = (
        np.stack(
            [(pixels[:, 0] - K[0, 2]) / K[0, 0], (pixels[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(pixels))],
            axis=1,
        )
        @ pose[:3, :3].T
    )
    hits = world.cast(pose[:3, 3], rays)
    return ((hits["points"] - pose[:3, 3]) @ pose[:3, :3])[:, 2]


def test_planar_pose_convention() -> None:
    # Yaw +90° is a left turn: the camera then looks along world −x, its right (x axis) along world +z.
    pose = planar_poses([2.0], [1.0], [np.pi / 2], height_m=1.5)[0]
    np.testing.assert_allclose(pose[:3, 2], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 0], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [-1.0, -1.5, 2.0])
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)


def test_loop_trajectory_drives_a_loop_and_revisits(loop: np.ndarray) -> None:
    assert loop.shape == (200, 4, 4)
    assert 260 < path_length_m(loop) < 300
    positions = loop[:, :3, 3]
    # Frames on the second lap pass within a few decimetres of the first frames, heading the same way.
    distances = np.linalg.norm(positions[120:] - positions[0], axis=1)
    revisit = 120 + int(np.argmin(distances))
    assert distances.min() < 1.0
    assert np.degrees(np.arccos(np.clip(loop[revisit, :3, 2] @ loop[0, :3, 2], -1, 1))) < 3.0
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    assert steps.min() > 0.9 and steps.max() < 1.9  # speed varies, never stops
    np.testing.assert_allclose(
        scale_trajectory(loop, 2.0)[:, :3, 3] - positions[0], 2 * (positions - positions[0])
    )


def test_level_trajectory_keeps_heading_and_position() -> None:
    pose = planar_poses([1.0], [2.0], [0.4])[0]
    tilt = np.array([[1, 0, 0], [0, np.cos(0.05), -np.sin(0.05)], [0, np.sin(0.05), np.cos(0.05)]])
    tilted = pose.copy()
    tilted[:3, :3] = pose[:3, :3] @ tilt  # pitch the camera down a little
    np.testing.assert_allclose(level_trajectory(tilted[None])[0], pose, atol=1e-12)


def test_stereo_pairs_are_subpixel_exact(
    world: StreetWorld, loop: np.ndarray, intrinsics: np.ndarray
) -> None:
    # Sub-pixel KLT disparities between the rendered left and right images equal f·b / true depth.
    for frame in (0, 80):
        left = world.render(loop[frame], intrinsics, SIZE)
        right = world.render(right_pose(loop[frame]), intrinsics, SIZE)
        corners = cv2.goodFeaturesToTrack(left, 300, 0.01, 5).reshape(-1, 2).astype(np.float32)
        assert len(corners) > 200  # plenty of trackable texture everywhere
        tracked, status, _ = cv2.calcOpticalFlowPyrLK(
            left, right, corners, None, winSize=(11, 11), maxLevel=3
        )
        ok = status.ravel() == 1
        disparity_true = intrinsics[0, 0] * BASELINE_M / true_depth_m(world, loop[frame], intrinsics, corners)
        error_px = np.abs(corners[:, 0] - tracked[:, 0] - disparity_true)[ok]
        assert ok.mean() > 0.9
        assert np.median(error_px) < 0.1 and np.percentile(error_px, 90) < 0.4
        assert np.median(np.abs(tracked[ok, 1] - corners[ok, 1])) < 0.1  # rectified: same rows


def test_consecutive_frames_are_consistent(
    world: StreetWorld, loop: np.ndarray, intrinsics: np.ndarray
) -> None:
    # Warping frame k+1 into frame k through the true depth reproduces frame k (up to resampling).
    width, height = SIZE
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    pose_k, pose_next = loop[40], loop[41]
    depth = true_depth_m(world, pose_k, intrinsics, pixels)
    rays = np.stack(
        [
            (pixels[:, 0] - intrinsics[0, 2]) / intrinsics[0, 0],
            (pixels[:, 1] - intrinsics[1, 2]) / intrinsics[1, 1],
            np.ones(len(pixels)),
        ],
        axis=1,
    )
    world_points = (rays * depth[:, None]) @ pose_k[:3, :3].T + pose_k[:3, 3]
    in_next = (world_points - pose_next[:3, 3]) @ pose_next[:3, :3]
    map_u = (intrinsics[0, 0] * in_next[:, 0] / in_next[:, 2] + intrinsics[0, 2]).reshape(height, width)
    map_v = (intrinsics[1, 1] * in_next[:, 1] / in_next[:, 2] + intrinsics[1, 2]).reshape(height, width)
    image_k = world.render(pose_k, intrinsics, SIZE).astype(np.float32)
    image_next = world.render(pose_next, intrinsics, SIZE).astype(np.float32)
    warped = cv2.remap(image_next, map_u.astype(np.float32), map_v.astype(np.float32), cv2.INTER_CUBIC)
    inside = (
        (map_u > 2)
        & (map_u < width - 3)
        & (map_v > 2)
        & (map_v < height - 3)
        & (depth.reshape(height, width) < 60)
    )
    assert inside.mean() > 0.5
    assert np.abs(warped - image_k)[inside].mean() < 4.0
    assert np.abs(image_next - image_k)[inside].mean() > 20.0  # the test is not trivially satisfied


def normalised_thumbnail(image: np.ndarray) -> np.ndarray:
    small = cv2.resize(image, (64, 20), interpolation=cv2.INTER_AREA).astype(float)
    return (small - small.mean()) / small.std()


def test_revisits_look_alike_and_places_differ(
    world: StreetWorld, loop: np.ndarray, intrinsics: np.ndarray
) -> None:
    positions = loop[:, :3, 3]
    revisit = 120 + int(np.argmin(np.linalg.norm(positions[120:] - positions[10], axis=1)))
    views = {
        k: normalised_thumbnail(world.render(loop[k], intrinsics, SIZE)) for k in (10, revisit, 30, 60, 100)
    }
    same_place = np.abs(views[10] - views[revisit]).mean()
    elsewhere = [np.abs(views[10] - views[k]).mean() for k in (30, 60, 100)]
    assert same_place < 0.5 * min(elsewhere)


def test_rendering_is_deterministic_per_seed(loop: np.ndarray, intrinsics: np.ndarray) -> None:
    first = StreetWorld(loop[:, :3, 3], seed=3).render(loop[5], intrinsics, SIZE)
    again = StreetWorld(loop[:, :3, 3], seed=3).render(loop[5], intrinsics, SIZE)
    other = StreetWorld(loop[:, :3, 3], seed=4).render(loop[5], intrinsics, SIZE)
    np.testing.assert_array_equal(first, again)
    assert np.abs(first.astype(int) - other).mean() > 10


def test_render_sequence_writes_a_kitti_sequence(tmp_path: Path, loop: np.ndarray) -> None:
    poses = loop[:12]
    root = render_sequence(poses, tmp_path / "synthetic", sequence="04", image_size_px=SIZE, noise_std=1.0)
    data = KittiOdometry(root, "04")
    assert len(data) == 12 and data.note == ""
    calib = data.calibration
    assert calib.image_size_px == SIZE and calib.baseline_m == pytest.approx(BASELINE_M)
    assert calib.P1[0, 3] == pytest.approx(-calib.fx * BASELINE_M)
    assert calib.fx == pytest.approx(KITTI_FOCAL_RATIO * SIZE[0])
    np.testing.assert_allclose(data.timestamps_s, np.arange(12) * 0.1)
    np.testing.assert_allclose(data.ground_truth(), poses, atol=1e-8)
    frame = data[11]
    assert frame.left.std() > 20 and frame.right.std() > 20
    # Thread count does not change the output.
    again = render_sequence(
        poses, tmp_path / "again", sequence="04", image_size_px=SIZE, noise_std=1.0, workers=1
    )
    np.testing.assert_array_equal(KittiOdometry(again, "04")[11].right, frame.right)


def test_bad_trajectories_are_rejected(tmp_path: Path, loop: np.ndarray) -> None:
    with pytest.raises(DatasetError, match="shape"):
        render_sequence(loop[:, :3, 3], tmp_path)
    bad = loop[:3].copy()
    bad[1, 0, 3] = np.nan
    with pytest.raises(DatasetError, match="NaN"):
        render_sequence(bad, tmp_path)
    with pytest.raises(DatasetError, match="street_half_width_m"):
        StreetWorld(loop[:, :3, 3], street_half_width_m=0.5)
    with pytest.raises(DatasetError, match="corner radius"):
        loop_trajectory(10, side_lengths_m=(10.0, 10.0), corner_radius_m=6.0)


@pytest.mark.data
def test_kitti_ground_truth_renders_with_its_real_loop(shared_data: Path) -> None:
    # Sequence 00 ends where it started: the last frames revisit the first street.
    poses = kitti_trajectory(shared_data / "kitti_odometry" / "poses" / "00.txt")
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-6)
    assert np.abs(poses[:, 1, 0]).max() < 1e-12 and np.abs(poses[:, 1, 2]).max() < 1e-12  # levelled
    world = StreetWorld(poses[:, :3, 3], seed=0)
    K = stereo_projections(SIZE, BASELINE_M, KITTI_FOCAL_RATIO)[0][:, :3]
    positions = poses[:, :3, 3]
    revisit = 4000 + int(np.argmin(np.linalg.norm(positions[4000:] - positions[20], axis=1)))
    assert np.linalg.norm(positions[revisit] - positions[20]) < 2.0
    views = {k: normalised_thumbnail(world.render(poses[k], K, SIZE)) for k in (20, revisit, 600, 2000)}
    same_place = np.abs(views[20] - views[revisit]).mean()
    assert same_place < 0.5 * min(np.abs(views[20] - views[k]).mean() for k in (600, 2000))


@pytest.mark.slow
def test_demo_sequence_is_rendered_once_and_reused(tmp_path: Path) -> None:
    root = demo_sequence(tmp_path / "demo")
    data = KittiOdometry(root, "00")
    assert len(data) == DEMO_FRAMES
    first_image = root / "sequences" / "00" / "image_0" / "000000.png"
    stamp = first_image.stat().st_mtime_ns
    assert demo_sequence(tmp_path / "demo") == root
    assert first_image.stat().st_mtime_ns == stamp  # cached, not rendered again
    gt = data.ground_truth()
    assert 260 < path_length_m(gt) < 300


def test_posts_stand_on_the_pavements_where_the_world_puts_them(loop, intrinsics):
    # Posts depend on the world position only: a street built from half of the loop has the same posts
    # there as the whole loop's; they stand 1-2.5 m in from the facades, off the lanes; a ray at a post's
    # centre stops at its surface (an exact range), and without posts the same ray reaches the facade.
    whole = StreetWorld(loop[:, :3, 3], seed=0, poles=True)
    half = StreetWorld(loop[:100, :3, 3], seed=0, poles=True)
    assert len(whole.poles_xz) >= 10
    centre_xz = loop[:, :3, 3][:, [0, 2]]
    distance = np.array([np.min(np.linalg.norm(centre_xz - p, axis=1)) for p in whole.poles_xz])
    assert distance.min() > 7.0 - 2.5 - 0.5  # the path's poses are 1-2 m apart: a little slack
    common = {tuple(np.round(p, 6)) for p in whole.poles_xz} & {tuple(np.round(p, 6)) for p in half.poles_xz}
    assert len(common) >= len(half.poles_xz) // 2
    camera = loop[0, :3, 3]
    offsets = whole.poles_xz - camera[[0, 2]]
    nearest = int(np.argmin(np.linalg.norm(offsets, axis=1)))
    direction = np.array([offsets[nearest, 0], 0.0, offsets[nearest, 1]])
    hit = whole.cast(camera, direction[None])
    plain = StreetWorld(loop[:, :3, 3], seed=0).cast(camera, direction[None])
    expected = np.linalg.norm(offsets[nearest]) - 0.25
    assert hit["kind"][0] == 2 and abs(hit["range_m"][0] - expected) < 1e-6
    assert plain["range_m"][0] > expected + 0.5
    # The default world has none: renders without posts are unchanged.
    assert StreetWorld(loop[:, :3, 3], seed=0).poles_xz is None
