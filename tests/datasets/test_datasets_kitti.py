"""KITTI odometry loader: layout, lazy frames, range/stride, ground truth, and clear errors on bad data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import as_colour_download
from hippo_nav.datasets import (
    DatasetError,
    KittiOdometry,
    StereoDataset,
    open_dataset,
)
from hippo_nav.io import write_kitti_poses

FX, CX, CY, BASELINE_M = 500.0, 31.5, 11.5, 0.5
CALIB = (
    f"P0: {FX} 0 {CX} 0 0 {FX} {CY} 0 0 0 1 0\n"
    f"P1: {FX} 0 {CX} {-FX * BASELINE_M} 0 {FX} {CY} 0 0 0 1 0\n"
    f"P2: {FX} 0 {CX} 44.8 0 {FX} {CY} 0.2 0 0 1 0.003\n"
    "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n"
)


def make_kitti(root: Path, n_frames: int = 12, n_images: int = 8, sequence: str = "03") -> Path:
    """A tiny KITTI tree: `n_frames` timestamps and poses, stereo images for the first `n_images`."""
    seq = root / "sequences" / sequence
    for cam in ("image_0", "image_1"):
        (seq / cam).mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n_images):
        for cam in ("image_0", "image_1"):
            image = rng.integers(0, 256, size=(24, 64), dtype=np.uint8)
            image[0, 0] = i  # identifies the frame
            cv2.imwrite(str(seq / cam / f"{i:06d}.png"), image)
    (seq / "calib.txt").write_text(CALIB)
    np.savetxt(seq / "times.txt", np.arange(n_frames) * 0.1, fmt="%.6e")
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    poses[:, 2, 3] = np.arange(n_frames) * 1.5
    write_kitti_poses(root / "poses" / f"{sequence}.txt", poses)
    return root


@pytest.fixture
def kitti_root(tmp_path: Path) -> Path:
    return make_kitti(tmp_path / "kitti")


def test_reads_calibration_frames_and_ground_truth(kitti_root: Path) -> None:
    data = KittiOdometry(kitti_root, "03")
    assert isinstance(data, StereoDataset)
    assert len(data) == 8 and list(data.frame_indices) == list(range(8))
    assert "8 of 12" in data.note
    calib = data.calibration
    assert calib.image_size_px == (64, 24)
    assert (calib.fx, calib.fy, calib.cx, calib.cy) == (FX, FX, CX, CY)
    assert calib.baseline_m == pytest.approx(BASELINE_M)
    assert calib.P3 is None and calib.P2 is not None
    np.testing.assert_array_equal(calib.K, [[FX, 0, CX], [0, FX, CY], [0, 0, 1]])
    frame = data[5]
    assert frame.index == 5 and frame.timestamp_s == pytest.approx(0.5)
    assert frame.left.dtype == np.uint8 and frame.left.shape == (24, 64) and frame.left[0, 0] == 5
    assert frame.right.shape == (24, 64)
    assert [f.index for f in data] == list(range(8))
    gt = data.ground_truth()
    assert gt is not None and gt.shape == (8, 4, 4)
    np.testing.assert_allclose(gt[:, 2, 3], np.arange(8) * 1.5)


def test_range_and_stride(kitti_root: Path) -> None:
    data = open_dataset(kitti_root, "03", start=1, stop=8, stride=3)
    assert list(data.frame_indices) == [1, 4, 7]
    np.testing.assert_allclose(data.timestamps_s, [0.1, 0.4, 0.7])
    assert data[2].left[0, 0] == 7 and data[-1].index == 7
    np.testing.assert_allclose(data.ground_truth()[:, 2, 3], [1.5, 6.0, 10.5])
    with pytest.raises(IndexError):
        data[3]


def test_frames_load_lazily(kitti_root: Path) -> None:
    data = KittiOdometry(kitti_root, "03")
    # Removing an image after construction only fails when that frame is asked for.
    (kitti_root / "sequences" / "03" / "image_1" / "000006.png").unlink()
    assert data[5].index == 5
    with pytest.raises(DatasetError, match=r"image_1/000006.png: image not found"):
        data[6]


def test_no_ground_truth_is_none(kitti_root: Path) -> None:
    (kitti_root / "poses" / "03.txt").unlink()
    assert KittiOdometry(kitti_root, "03").ground_truth() is None


def test_wrong_root_and_sequence(tmp_path: Path, kitti_root: Path) -> None:
    with pytest.raises(DatasetError, match="no sequences/ folder"):
        KittiOdometry(tmp_path, "03")
    with pytest.raises(DatasetError, match="sequence not found; present: 03"):
        KittiOdometry(kitti_root, "07")
    with pytest.raises(DatasetError, match="dataset folder not found"):
        open_dataset(tmp_path / "nowhere")
    with pytest.raises(DatasetError, match="no loader recognises"):
        open_dataset(tmp_path / "kitti" / "poses")
    with pytest.raises(DatasetError, match="unknown dataset kind"):
        open_dataset(kitti_root, "03", kind="lidar")


def test_missing_images(kitti_root: Path) -> None:
    with pytest.raises(DatasetError, match=r"image_0/000008.png: image missing for requested frame 8"):
        KittiOdometry(kitti_root, "03", start=5, stop=10)
    with pytest.raises(DatasetError, match="outside the sequence"):
        KittiOdometry(kitti_root, "03", start=5, stop=40)
    for image in (kitti_root / "sequences" / "03" / "image_1").iterdir():
        image.unlink()
    with pytest.raises(DatasetError, match="no frame from 0 on has both image_0 and image_1"):
        KittiOdometry(kitti_root, "03")


def test_corrupt_image_and_mismatched_stereo_sizes(kitti_root: Path) -> None:
    seq = kitti_root / "sequences" / "03"
    (seq / "image_0" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    cv2.imwrite(str(seq / "image_1" / "000003.png"), np.zeros((20, 64), np.uint8))
    data = KittiOdometry(kitti_root, "03")
    with pytest.raises(DatasetError, match=r"image_0/000002.png: image is corrupt"):
        data[2]
    with pytest.raises(
        DatasetError, match=r"image_1/000003.png: size \(64, 20\) differs from the left image"
    ):
        data[3]


@pytest.mark.parametrize(
    ("calib", "phrase"),
    [
        (CALIB.replace(f"{-FX * BASELINE_M} ", ""), r"calib.txt:2: P1 needs 12 numbers"),
        (CALIB.replace("P2: 500.0", "P2: five"), r"calib.txt:3: P2: not a number"),
        ("P0: " + CALIB.split("P0: ")[1].split("\n")[0] + "\n", "no P1 line"),
        (CALIB.replace(f"P1: {FX}", "P1: 510"), "not a rectified pair"),
        (CALIB.replace(f"{-FX * BASELINE_M}", f"{FX * BASELINE_M}"), "must be negative"),
        ("P0 500 0 0\n", r"calib.txt:1: expected 'KEY: numbers'"),
    ],
)
def test_malformed_calibration(kitti_root: Path, calib: str, phrase: str) -> None:
    (kitti_root / "sequences" / "03" / "calib.txt").write_text(calib)
    with pytest.raises(DatasetError, match=phrase):
        KittiOdometry(kitti_root, "03")


def test_text_files_saved_with_a_byte_order_mark_read_as_without(kitti_root: Path) -> None:
    # Editors on Windows start UTF-8 files with a byte-order mark; calib.txt then had "no P0 line".
    plain = KittiOdometry(kitti_root, "03")
    seq = kitti_root / "sequences" / "03"
    for name in ("calib.txt", "times.txt"):
        (seq / name).write_bytes(b"\xef\xbb\xbf" + (seq / name).read_bytes())
    marked = KittiOdometry(kitti_root, "03")
    for name in ("fx", "fy", "cx", "cy", "baseline_m"):
        assert getattr(marked.calibration, name) == getattr(plain.calibration, name)
    np.testing.assert_array_equal(marked.timestamps_s, plain.timestamps_s)


def test_malformed_times_and_short_pose_file(kitti_root: Path) -> None:
    seq = kitti_root / "sequences" / "03"
    (seq / "times.txt").write_text("0.0\n0.1\nzero point two\n")
    with pytest.raises(DatasetError, match=r"times.txt:3: not a timestamp"):
        KittiOdometry(kitti_root, "03")
    np.savetxt(seq / "times.txt", np.arange(12) * 0.1)
    write_kitti_poses(kitti_root / "poses" / "03.txt", np.tile(np.eye(4), (5, 1, 1)))
    # The ground truth is read and checked when the dataset is opened, not after the last frame.
    with pytest.raises(DatasetError, match=r"03.txt: holds 5 poses but .*times.txt lists 12 frames"):
        KittiOdometry(kitti_root, "03")
    (kitti_root / "poses" / "03.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0\n")
    with pytest.raises(DatasetError, match=r"03.txt:2: expected 12 numbers"):
        KittiOdometry(kitti_root, "03")
    np.savetxt(seq / "times.txt", [0.0, 0.1, 0.1, 0.3])
    with pytest.raises(DatasetError, match=r"times.txt:3: timestamp 0.1 repeats the previous one"):
        KittiOdometry(kitti_root, "03")


def test_frames_are_never_dropped_silently(kitti_root: Path) -> None:
    seq = kitti_root / "sequences" / "03"
    (seq / "image_1" / "000004.png").unlink()  # a hole inside the available frames 0..7
    data = KittiOdometry(kitti_root, "03")
    assert list(data.frame_indices) == [0, 1, 2, 3, 5, 6, 7] and data.missing_frames == [4]
    assert any("lack a stereo image" in w for w in data.warnings) and "(4)" in data.note
    # --start alone uses the frames available from there on.
    assert list(KittiOdometry(kitti_root, "03", start=5).frame_indices) == [5, 6, 7]
    # More images than timestamps: the extra images are reported, not silently ignored.
    np.savetxt(seq / "times.txt", np.arange(6) * 0.1)
    write_kitti_poses(kitti_root / "poses" / "03.txt", np.tile(np.eye(4), (6, 1, 1)))
    short = KittiOdometry(kitti_root, "03")
    assert short.frames_without_timestamp == 2 and "have no timestamp" in short.note


@pytest.mark.data
def test_real_kitti_sequences(shared_data: Path) -> None:
    root = shared_data / "kitti_odometry"
    data = open_dataset(root, "01")
    assert len(data) == 51 and "51 of 1101" in data.note
    assert data.calibration.image_size_px == (1241, 376)
    assert data.calibration.baseline_m == pytest.approx(0.537, abs=1e-3)
    frame = data[50]
    assert frame.left.shape == frame.right.shape == (376, 1241)
    gt = data.ground_truth()
    assert gt.shape == (51, 4, 4)
    # The ground truth rows are those of the yielded frames: ~45 m driven (curving right) in these 5 s.
    assert data.timestamps_s[-1] == pytest.approx(5.185, abs=1e-3)
    assert 40 < np.linalg.norm(gt[-1, :3, 3] - gt[0, :3, 3]) < 50
    urban = KittiOdometry(root, "06", start=10, stop=40, stride=10)
    assert urban.calibration.image_size_px == (1226, 370) and list(urban.frame_indices) == [10, 20, 30]
    with pytest.raises(DatasetError, match="image_1: folder missing"):
        KittiOdometry(root, "00")  # only left images are shared for 00


# KITTI's colour cameras: camera 2 about 6 cm left of camera 0 (P2's t_x = +0.06 m), camera 3 a baseline right
# of camera 2, both with camera 0's intrinsics.
T2_X_M = 0.06
COLOUR_CALIB = (
    f"P0: {FX} 0 {CX} 0 0 {FX} {CY} 0 0 0 1 0\n"
    f"P1: {FX} 0 {CX} {-FX * 0.54} 0 {FX} {CY} 0 0 0 1 0\n"
    f"P2: {FX} 0 {CX} {FX * T2_X_M} 0 {FX} {CY} 0 0 0 1 0\n"
    f"P3: {FX} 0 {CX} {FX * (T2_X_M - BASELINE_M)} 0 {FX} {CY} 0 0 0 1 0\n"
)


def _colour_only(root: Path) -> Path:
    """`make_kitti`'s tree as KITTI's colour download alone: image_2/image_3 (colour PNGs), P2/P3."""
    seq = root / "sequences" / "03"
    as_colour_download(seq, keep_gray=False)
    (seq / "calib.txt").write_text(COLOUR_CALIB)
    return root


def test_the_colour_download_is_read_as_a_gray_pair_in_camera_2_s_frame(kitti_root: Path) -> None:
    gray = KittiOdometry(kitti_root, "03")
    gray_frame, gray_gt = gray[5], gray.ground_truth()
    colour = KittiOdometry(_colour_only(kitti_root), "03")
    assert colour.cameras == "color" and "image_2, image_3" in colour.note
    calib = colour.calibration
    # The pair's own calibration: camera 2 at the origin, camera 3 a baseline to its right.
    assert calib.baseline_m == pytest.approx(BASELINE_M)
    np.testing.assert_array_equal(calib.P0[:, 3], 0.0)
    np.testing.assert_array_equal(calib.K, gray.calibration.K)
    frame = colour[5]
    assert frame.left.ndim == 2 and frame.left.dtype == np.uint8
    np.testing.assert_array_equal(frame.left, gray_frame.left)
    np.testing.assert_array_equal(frame.right, gray_frame.right)
    # Camera 2's ground truth: camera 0's poses moved 6 cm to camera 0's left (x = −0.06 m in its frame).
    offset = np.linalg.inv(gray_gt) @ colour.ground_truth()
    np.testing.assert_allclose(offset[:, :3, 3], np.tile([-T2_X_M, 0.0, 0.0], (len(colour), 1)), atol=1e-12)
    np.testing.assert_allclose(offset[:, :3, :3], np.tile(np.eye(3), (len(colour), 1, 1)), atol=1e-12)


def test_the_gray_pair_is_preferred_and_either_can_be_asked_for(kitti_root: Path) -> None:
    seq = kitti_root / "sequences" / "03"
    as_colour_download(seq)
    (seq / "calib.txt").write_text(COLOUR_CALIB)
    assert KittiOdometry(kitti_root, "03").cameras == "gray"
    assert KittiOdometry(kitti_root, "03").calibration.baseline_m == pytest.approx(0.54)
    assert KittiOdometry(kitti_root, "03", cameras="color").calibration.baseline_m == pytest.approx(
        BASELINE_M
    )
    assert open_dataset(kitti_root, "03", cameras="color").cameras == "color"


def test_a_missing_or_unknown_pair_says_which_folders_it_needs(kitti_root: Path) -> None:
    with pytest.raises(
        DatasetError, match=r"cameras = 'color' needs image_2 and image_3; present: image_0, image_1"
    ):
        KittiOdometry(kitti_root, "03", cameras="color")
    with pytest.raises(DatasetError, match=r"cameras = 'rgb': use one of 'gray', 'color'"):
        KittiOdometry(kitti_root, "03", cameras="rgb")
    _colour_only(kitti_root)
    (kitti_root / "sequences" / "03" / "calib.txt").write_text(CALIB)  # no P3 line
    with pytest.raises(DatasetError, match="no P3 line; P2 .left. and P3 .right. are required"):
        KittiOdometry(kitti_root, "03")
    for folder in ("image_2", "image_3"):
        for path in (kitti_root / "sequences" / "03" / folder).iterdir():
            path.unlink()
        (kitti_root / "sequences" / "03" / folder).rmdir()
    with pytest.raises(
        DatasetError, match=r"image_0: folder missing; .* or image_2 and image_3 \(its colour"
    ):
        KittiOdometry(kitti_root, "03")
