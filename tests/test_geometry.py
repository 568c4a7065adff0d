"""The frame convention (`hippo_nav.geometry`, docs/spec.md §9): camera x right, y down, z forward; the
planar map frame x = forward, y = left, yaw counter-clockwise (a left turn); SE(2) composition as the Rust
map composes."""

from __future__ import annotations

import numpy as np
import pytest
from hippo_nav.geometry import (
    lift_planar,
    planar_from_pose,
    planar_step,
    planar_xy,
    pose_from_planar,
    se2_between,
    se2_chain,
    se2_compose,
    wrap_angle,
    yaw_rotation,
)
from hippo_nav.map import new_experience_map
from hippo_nav.synthetic import planar_poses


def _translation(x: float, y: float, z: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = (x, y, z)
    return pose


def _rotation_about(axis: str, angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    rotations = {
        "x": [[1, 0, 0], [0, c, -s], [0, s, c]],
        "y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
        "z": [[c, -s, 0], [s, c, 0], [0, 0, 1]],
    }
    pose = np.eye(4)
    pose[:3, :3] = rotations[axis]
    return pose


def test_camera_axes_map_to_the_planar_axes():
    # Forward (camera +z) is the map's +x, the camera's left (−x) is the map's +y; height (y down) is not
    # planar.
    assert planar_from_pose(_translation(0.0, 0.0, 2.0)) == pytest.approx([2.0, 0.0, 0.0])
    assert planar_from_pose(_translation(-1.5, 0.0, 0.0)) == pytest.approx([0.0, 1.5, 0.0])
    assert planar_from_pose(_translation(0.0, -3.0, 0.0)) == pytest.approx([0.0, 0.0, 0.0])
    np.testing.assert_allclose(planar_xy(np.stack([_translation(1.0, 7.0, 4.0)] * 2)), [[4.0, -1.0]] * 2)


def test_a_left_turn_is_a_positive_yaw_about_the_cameras_minus_y_axis():
    # Turning left by 90°: the camera's forward axis ends up along the first camera's left (world −x).
    turned = _rotation_about("y", -np.pi / 2)
    np.testing.assert_allclose(turned[:3, :3] @ [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], atol=1e-12)
    assert planar_from_pose(turned)[2] == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(yaw_rotation(np.pi / 2), turned[:3, :3], atol=1e-12)
    # Pitch and roll (about the camera's x and z axes) do not change the yaw.
    tilted = turned @ _rotation_about("x", 0.2) @ _rotation_about("z", -0.1)
    assert planar_from_pose(tilted)[2] == pytest.approx(np.pi / 2)


def test_planar_poses_round_trip_through_3d():
    rng = np.random.default_rng(3)
    planar = np.column_stack(
        [rng.uniform(-50, 50, 20), rng.uniform(-50, 50, 20), rng.uniform(-np.pi, np.pi, 20)]
    )
    np.testing.assert_allclose(planar_from_pose(pose_from_planar(planar, height_m=1.7)), planar, atol=1e-12)
    # Any 3-D pose splits into its planar part and the rest, and goes back together exactly.
    tilt = _rotation_about("x", 0.05) @ _rotation_about("z", -0.03)
    poses = pose_from_planar(planar, height_m=1.7) @ tilt
    poses[:, 1, 3] += rng.normal(0, 0.2, 20)
    np.testing.assert_allclose(lift_planar(planar_from_pose(poses), poses), poses, atol=1e-12)


def test_se2_composition_and_its_inverse():
    a = np.array([1.0, 0.0, np.pi / 2])
    # One metre forward after turning left by 90° at (1, 0) is (1, 1).
    np.testing.assert_allclose(se2_compose(a, [1.0, 0.0, 0.0]), [1.0, 1.0, np.pi / 2], atol=1e-12)
    rng = np.random.default_rng(5)
    for _ in range(10):
        p, q = rng.uniform(-5, 5, 3), rng.uniform(-5, 5, 3)
        q[2] = wrap_angle(q[2])
        np.testing.assert_allclose(se2_between(p, se2_compose(p, q)), q, atol=1e-12)
    assert wrap_angle(np.pi) == pytest.approx(-np.pi) and wrap_angle(-np.pi) == pytest.approx(-np.pi)
    assert wrap_angle(3 * np.pi / 2) == pytest.approx(-np.pi / 2)


def test_planar_step_follows_the_kitti_camera_conventions():
    # A level camera that drove 2 m forward and 0.5 m to its left while turning 0.1 rad to the left.
    start, end = planar_poses([0.0, 2.0], [0.0, 0.5], [0.0, 0.1])
    forward, left, yaw = planar_step(np.linalg.inv(start) @ end)
    assert (forward, left, yaw) == pytest.approx((2.0, 0.5, 0.1), abs=1e-12)
    # Seen from a turned camera the same world motion is expressed in that camera's axes.
    start, end = planar_poses([0.0, 0.0], [0.0, 1.0], [np.pi / 2, np.pi / 2])
    assert planar_step(np.linalg.inv(start) @ end) == pytest.approx((1.0, 0.0, 0.0), abs=1e-12)


def test_the_rust_map_composes_odometry_steps_as_the_python_frames_do():
    """The experience map (Rust) dead-reckons its agent with the same SE(2) composition: the planar steps
    of a drive, fed to the map, put the agent where `se2_chain` puts it."""
    rng = np.random.default_rng(11)
    steps = np.column_stack(
        [rng.uniform(0.5, 1.5, 30), rng.uniform(-0.1, 0.1, 30), rng.uniform(-0.2, 0.2, 30)]
    )
    steps[0] = 0.0
    experience_map = new_experience_map()
    for step in steps:
        outcome = experience_map.on_frame(None, (0.0, 0.0), 0.0, tuple(step), 0.1)
    np.testing.assert_allclose(outcome.world_from_agent, se2_chain(steps)[-1], atol=1e-9)


def test_planar_helpers_refuse_arrays_of_another_size():
    # Before: a 4- or 5-vector was cut to its first three values without a word.
    from hippo_nav._core import HippoNavError
    from hippo_nav.geometry import pose_from_planar, se2_between, se2_compose, skew

    for call in (
        lambda: se2_compose([1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 0.0]),
        lambda: se2_between([0.0, 0.0, 0.0], [1.0, 2.0]),
        lambda: pose_from_planar([1.0, 2.0, 3.0, 4.0, 5.0]),
        lambda: skew([1.0, 2.0, 3.0, 4.0]),
    ):
        with pytest.raises(HippoNavError, match="must be \\(…, 3\\) arrays"):
            call()
