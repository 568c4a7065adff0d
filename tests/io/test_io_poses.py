"""Pose files: KITTI and TUM round trips, evo reads what we write, and malformed files name file and line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hippo_nav import HippoNavError
from hippo_nav.io import (
    DatasetError,
    matrix_from_quaternion,
    quaternion_from_matrix,
    read_kitti_poses,
    read_tum,
    write_kitti_poses,
    write_tum,
)


def random_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        q, r = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.diag(r))
        if np.linalg.det(q) < 0:
            q[:, 0] *= -1
        poses[k, :3, :3] = q
        poses[k, :3, 3] = rng.normal(scale=100.0, size=3)
    return poses


def test_kitti_round_trip_accepts_any_layout(tmp_path: Path) -> None:
    poses = random_poses(20)
    fortran = np.asfortranarray(poses)
    strided = np.repeat(poses, 2, axis=0)[::2]  # a non-contiguous view of the same poses
    for k, layout in enumerate((poses, fortran, strided, poses[:, :3, :])):
        path = write_kitti_poses(tmp_path / f"p{k}.txt", layout)
        np.testing.assert_allclose(read_kitti_poses(path), poses, atol=1e-7)


def test_tum_round_trip_and_quaternion_conventions(tmp_path: Path) -> None:
    poses = random_poses(30, seed=1)
    stamps = np.linspace(0.0, 2.9, 30)
    stamps_read, poses_read = read_tum(write_tum(tmp_path / "t.txt", stamps, poses))
    np.testing.assert_allclose(stamps_read, stamps, atol=1e-9)
    np.testing.assert_allclose(poses_read, poses, atol=1e-7)
    # 90° about z: (qx, qy, qz, qw) = (0, 0, sin 45°, cos 45°), Hamilton convention.
    rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(quaternion_from_matrix(rz), [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(matrix_from_quaternion([0, 0, np.sqrt(0.5), np.sqrt(0.5)]), rz, atol=1e-12)


def test_quaternions_agree_with_evo() -> None:
    transformations = pytest.importorskip("evo.core.transformations")
    for pose in random_poses(50, seed=2):
        ours = quaternion_from_matrix(pose[:3, :3])
        wxyz = transformations.quaternion_from_matrix(pose)
        theirs = np.r_[wxyz[1:], wxyz[0]]
        theirs *= np.sign(theirs[3])
        np.testing.assert_allclose(ours, theirs, atol=1e-12)


def test_evo_reads_the_files_we_write(tmp_path: Path) -> None:
    file_interface = pytest.importorskip("evo.tools.file_interface")
    poses = random_poses(15, seed=3)
    stamps = np.arange(15) * 0.1
    kitti = file_interface.read_kitti_poses_file(str(write_kitti_poses(tmp_path / "k.txt", poses)))
    np.testing.assert_allclose(np.array(kitti.poses_se3), poses, atol=1e-7)
    tum = file_interface.read_tum_trajectory_file(str(write_tum(tmp_path / "t.txt", stamps, poses)))
    np.testing.assert_allclose(np.array(tum.poses_se3), poses, atol=1e-7)
    np.testing.assert_allclose(tum.timestamps, stamps, atol=1e-9)


GOOD_LINE = "1 0 0 0 0 1 0 0 0 0 1 0"


@pytest.mark.parametrize(
    ("text", "line", "phrase"),
    [
        (f"{GOOD_LINE}\n1 0 0 0 0 1 0 0 0 0 1\n", 2, "expected 12 numbers"),
        (f"{GOOD_LINE}\n{GOOD_LINE}\n1 0 0 x 0 1 0 0 0 0 1 0\n", 3, "not a number"),
        ("1 0 0 nan 0 1 0 0 0 0 1 0\n", 1, "NaN"),
        (f"{GOOD_LINE}\n2 0 0 0 0 1 0 0 0 0 1 0\n", 2, "not a rotation"),
        (f"{GOOD_LINE}\n\n{GOOD_LINE}\n", 2, "blank line"),
        (f"# x y z\n{GOOD_LINE}\n", 1, "found 4; this is a comment line, which the format has none of"),
        (f"{GOOD_LINE.replace(' ', ',')}\n", 1, "found 1; the numbers are separated by commas"),
    ],
)
def test_malformed_kitti_pose_file_names_file_and_line(
    tmp_path: Path, text: str, line: int, phrase: str
) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(DatasetError, match=phrase) as info:
        read_kitti_poses(path)
    assert f"{path}:{line}" in str(info.value)
    assert isinstance(info.value, HippoNavError) and isinstance(info.value, ValueError)


def test_missing_and_empty_pose_files(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not found"):
        read_kitti_poses(tmp_path / "absent.txt")
    (tmp_path / "empty.txt").write_text("\n")
    with pytest.raises(DatasetError, match="empty"):
        read_kitti_poses(tmp_path / "empty.txt")


def test_malformed_tum_files(tmp_path: Path) -> None:
    path = tmp_path / "bad.tum"
    path.write_text("# t x y z qx qy qz qw\n0.0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 0 2\n")
    with pytest.raises(DatasetError, match=r"bad.tum:3: quaternion norm"):
        read_tum(path)
    path.write_text("0.2 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 0 1\n")
    with pytest.raises(DatasetError, match="increase"):
        read_tum(path)
    path.write_text("0.2 1 2 3 0 0 1\n")
    with pytest.raises(DatasetError, match=r"bad.tum:1: expected 8 numbers"):
        read_tum(path)


def test_writers_reject_bad_arrays(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="shape"):
        write_kitti_poses(tmp_path / "x.txt", np.zeros((3, 4)))
    poses = random_poses(2)
    poses[1, 0, 3] = np.inf
    with pytest.raises(DatasetError, match="NaN or infinity"):
        write_kitti_poses(tmp_path / "x.txt", poses)
    with pytest.raises(DatasetError, match="timestamps for"):
        write_tum(tmp_path / "x.txt", np.zeros(3), random_poses(2))
    # What the readers refuse is not written (TUM wrote a reflection, a zero block or 3·I as the identity).
    for block in (np.diag([-1.0, 1.0, 1.0]), np.zeros((3, 3)), 3.0 * np.eye(3)):
        poses = random_poses(2)
        poses[1, :3, :3] = block
        for write in (
            lambda p: write_kitti_poses(tmp_path / "x.txt", p),
            lambda p: write_tum(tmp_path / "x.txt", [0.0, 1.0], p),
        ):
            with pytest.raises(DatasetError, match="pose #1 is not .* a proper rotation"):
                write(poses)
    far = random_poses(2)
    far[0, 2, 3] = 2e9
    with pytest.raises(DatasetError, match="pose #0 lies more than"):
        write_kitti_poses(tmp_path / "x.txt", far)
    with pytest.raises(DatasetError, match="no poses to write"):
        write_kitti_poses(tmp_path / "x.txt", np.zeros((0, 4, 4)))


@pytest.mark.data
def test_reads_the_official_ground_truth(shared_data: Path) -> None:
    poses = read_kitti_poses(shared_data / "kitti_odometry" / "poses" / "00.txt")
    assert poses.shape == (4541, 4, 4)
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-6)
    # Sequence 00 is a 3.7 km drive.
    assert 3700 < np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum() < 3750
