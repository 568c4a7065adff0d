"""Plain stereo folder (left/, right/, calibration.yaml, times.txt, ground_truth.tum): a rendered synthetic
sequence written in that layout reads back frame for frame, with its calibration, times and ground truth;
every bad input is a one-line error naming the file."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.datasets import DatasetError, KittiOdometry, StereoDataset, StereoFolder, open_dataset
from hippo_nav.io import write_tum

N_FRAMES = 12  # frames of the shared `rendered` loop (conftest.py)
T0_S = 1000.0


def write_folder(
    kitti: KittiOdometry, folder: Path, *, times: bool = True, ground_truth: bool = True
) -> Path:
    """The rendered sequence as a stereo folder: names 1.png … 12.png (natural order), right images in
    colour, times from T0_S, the ground truth in TUM at the image times."""
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for frame in kitti:
        cv2.imwrite(str(folder / "left" / f"{frame.index + 1}.png"), frame.left)
        cv2.imwrite(
            str(folder / "right" / f"{frame.index + 1}.png"), cv2.cvtColor(frame.right, cv2.COLOR_GRAY2BGR)
        )
    c = kitti.calibration
    (folder / "calibration.yaml").write_text(
        f"# rectified pair\nfx: {c.fx!r}\nfy: {c.fy!r}\ncx: {c.cx!r}\ncy: {c.cy!r}\nbaseline_m: {c.baseline_m!r}\n"
        f"width: {c.image_size_px[0]}\nheight: {c.image_size_px[1]}\n"
    )
    stamps = T0_S + kitti.timestamps_s
    if times:
        np.savetxt(folder / "times.txt", stamps, fmt="%.6f")
    if ground_truth:
        write_tum(folder / "ground_truth.tum", stamps, kitti.ground_truth())
    return folder


@pytest.fixture
def folder(rendered: KittiOdometry, tmp_path: Path) -> Path:
    return write_folder(rendered, tmp_path / "pairs")


def test_reads_back_frames_calibration_times_and_ground_truth(rendered: KittiOdometry, folder: Path) -> None:
    data = open_dataset(folder)
    assert isinstance(data, StereoFolder) and isinstance(data, StereoDataset)
    assert data.name == "pairs" and len(data) == N_FRAMES and data.note == ""
    np.testing.assert_allclose(data.calibration.P0, rendered.calibration.P0, rtol=1e-12)
    np.testing.assert_allclose(data.calibration.P1, rendered.calibration.P1, rtol=1e-12)
    assert data.calibration.baseline_m == pytest.approx(0.537) and data.calibration.image_size_px == (64, 24)
    np.testing.assert_allclose(data.timestamps_s, T0_S + np.arange(N_FRAMES) / 10)
    # Natural name order: 10.png is frame 9, not frame 1; colour right images come back gray.
    for i in (0, 1, 9, 11):
        frame, truth = data[i], rendered[i]
        assert frame.index == i and frame.timestamp_s == pytest.approx(T0_S + i / 10)
        np.testing.assert_array_equal(frame.left, truth.left)
        np.testing.assert_array_equal(frame.right, truth.right)
    np.testing.assert_allclose(data.ground_truth(), rendered.ground_truth(), atol=1e-8)


def test_range_and_stride(folder: Path, rendered: KittiOdometry) -> None:
    data = open_dataset(folder, start=2, stop=11, stride=4)
    assert list(data.frame_indices) == [2, 6, 10]
    np.testing.assert_array_equal(data[1].left, rendered[6].left)
    np.testing.assert_allclose(data.ground_truth(), rendered.ground_truth()[[2, 6, 10]], atol=1e-8)
    with pytest.raises(DatasetError, match=r"frame range \[3, 40\) is empty or outside the sequence"):
        StereoFolder(folder, start=3, stop=40)


def test_ground_truth_is_interpolated_and_trimmed(folder: Path, rendered: KittiOdometry) -> None:
    truth = rendered.ground_truth()
    stamps = T0_S + rendered.timestamps_s
    # Samples start at frame 2 and skip frame 6: frames 0, 1 are left out, frame 6 is interpolated.
    keep = [i for i in range(N_FRAMES) if i >= 2 and i != 6]
    write_tum(folder / "ground_truth.tum", stamps[keep], truth[keep])
    data = StereoFolder(folder)
    assert list(data.frame_indices) == list(range(2, N_FRAMES))
    assert "2 frame(s) outside the ground truth's time span" in data.note
    gt = data.ground_truth()
    np.testing.assert_allclose(gt[6 - 2, :3, 3], truth[6, :3, 3], atol=0.05)  # a curve, ~1.5 m per frame
    np.testing.assert_allclose(gt[5 - 2], truth[5], atol=1e-8)
    # Without trimming every frame is used and there is no ground truth.
    loose = StereoFolder(folder, trim_to_ground_truth=False)
    assert len(loose) == N_FRAMES and loose.ground_truth() is None


def test_defaults_without_times_and_ground_truth(rendered: KittiOdometry, tmp_path: Path) -> None:
    folder = write_folder(rendered, tmp_path / "bare", times=False, ground_truth=False)
    data = StereoFolder(folder, frame_rate_hz=20.0)
    np.testing.assert_allclose(data.timestamps_s, np.arange(N_FRAMES) / 20)
    assert data.ground_truth() is None
    (folder / "calibration.yaml").write_text("fx: 37\nfy: 37\ncx: 31.5\ncy: 11.5\nbaseline: 0.3\n")
    assert StereoFolder(folder).calibration.baseline_m == pytest.approx(0.3)


def test_unequal_pair_counts(folder: Path) -> None:
    (folder / "right" / "5.png").unlink()
    with pytest.raises(
        DatasetError, match=r"pairs: left/ holds 12 images but right/ holds 11; every left image"
    ):
        open_dataset(folder)


@pytest.mark.parametrize(
    ("calibration", "phrase"),
    [
        ("fx: 37\nfy: 37\ncx: 31.5\ncy: 11.5\n", r"calibration.yaml: no 'baseline_m' key"),
        (
            "fx: -37\nfy: 37\ncx: 31.5\ncy: 11.5\nbaseline_m: 0.5\n",
            r"'fx: -37' must be a positive finite number",
        ),
        ("fx: 37\nfy: 37\ncx: 31.5\ncy: eleven\nbaseline_m: 0.5\n", r"'cy: eleven' is not a number"),
        (
            "fx: 37\nfy: 37\ncx: 31.5\ncy: 11.5\nbaseline_m: 0.5\nwidth: 640\n",
            r"width: 640 but 1.png is 64x24 px",
        ),
        ("fx: [37\n", r"calibration.yaml:2: not valid YAML"),
        ("- 37\n- 37\n", "expected a YAML mapping"),
    ],
)
def test_bad_calibration(folder: Path, calibration: str, phrase: str) -> None:
    (folder / "calibration.yaml").write_text(calibration)
    with pytest.raises(DatasetError, match=phrase) as error:
        StereoFolder(folder)
    assert "\n" not in str(error.value)


def test_bad_times_and_ground_truth(folder: Path) -> None:
    times = folder / "times.txt"
    good = times.read_text()
    times.write_text("\n".join(good.splitlines()[:-1]) + "\n")
    with pytest.raises(DatasetError, match=r"times.txt: holds 11 timestamps for 12 image pairs"):
        StereoFolder(folder)
    times.write_text(good.replace("1000.200000", "1000.050000"))
    with pytest.raises(
        DatasetError, match=r"times.txt:3: timestamp 1000.05 does not increase \(previous 1000.1\)"
    ):
        StereoFolder(folder)
    times.write_text(good)
    gt = folder / "ground_truth.tum"
    lines = gt.read_text().splitlines()
    gt.write_text("\n".join([*lines[:3], "1000.3 0 0 0 0 0 0", *lines[4:]]) + "\n")
    with pytest.raises(DatasetError, match=r"ground_truth.tum:4: expected 8 numbers"):
        StereoFolder(folder)


def test_missing_parts_and_bad_images(folder: Path, tmp_path: Path) -> None:
    data = StereoFolder(folder)
    (folder / "left" / "3.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    cv2.imwrite(str(folder / "right" / "4.png"), np.zeros((20, 64), np.uint8))
    with pytest.raises(DatasetError, match=r"left/3.png: image is corrupt"):
        data[2]
    with pytest.raises(DatasetError, match=r"right/4.png: size \(64, 20\) differs from the first left image"):
        data[3]
    (folder / "calibration.yaml").unlink()
    assert not StereoFolder.detect(folder)
    with pytest.raises(DatasetError, match="calibration.yaml: calibration .* not found"):
        StereoFolder(folder)
    shutil.rmtree(folder / "right")
    with pytest.raises(DatasetError, match="right: folder missing"):
        StereoFolder(folder)
    (tmp_path / "empty" / "left").mkdir(parents=True)
    with pytest.raises(DatasetError, match="left: no images"):
        StereoFolder(tmp_path / "empty")


def test_an_image_missing_on_each_side_is_refused_not_paired_across_frames(folder: Path) -> None:
    """One image gone from each side keeps the counts equal: pairing by position would put frames of two
    moments together (a wrong depth for every frame between them)."""
    (folder / "left" / "3.png").unlink()
    (folder / "right" / "9.png").unlink()
    with pytest.raises(DatasetError, match=r"image 2 of each is left/4\.png but right/3\.png.*left/ lacks"):
        StereoFolder(folder)


def test_names_numbered_by_each_cameras_clock_are_paired_by_position(folder: Path) -> None:
    """Names that never agree (each camera's own timestamps) say nothing of a missing image."""
    for k, image in enumerate(sorted((folder / "right").iterdir(), key=lambda p: int(p.stem))):
        image.rename(folder / "right" / f"{5000 + 3 * k}.png")
    assert len(StereoFolder(folder)) == N_FRAMES


@pytest.mark.parametrize(
    ("times_factor", "gt_factor", "phrase"),
    [
        (1e3, 1.0, r"look like milliseconds"),  # checked before trimming to the ground truth (1 frame left)
        (1e-6, 1e-6, r"a camera taking 1e\+07 images a second"),  # milliseconds read as nanoseconds
        (1.0, 1e9, r"ground_truth\.tum: its samples are a median 1e\+08 apart.*another unit"),
    ],
)
def test_timestamps_in_another_unit_are_refused_before_the_ground_truth_trims_them(
    folder: Path, rendered: KittiOdometry, times_factor: float, gt_factor: float, phrase: str
) -> None:
    stamps = (T0_S if gt_factor <= 1 else 0.0) + rendered.timestamps_s  # TUM allows ±1e11 s
    np.savetxt(folder / "times.txt", stamps * times_factor, fmt="%.9g")
    write_tum(folder / "ground_truth.tum", stamps * gt_factor, rendered.ground_truth())
    with pytest.raises(DatasetError, match=phrase):
        StereoFolder(folder)


def test_calibration_keys_it_does_not_take_are_refused(folder: Path) -> None:
    """The images must be rectified: a distortion given here would be dropped without a word, a typo
    (`widht`) leave its check undone."""
    calib = folder / "calibration.yaml"
    text = calib.read_text()
    calib.write_text(text + "k1: -0.3\nwidht: 64\n")
    with pytest.raises(DatasetError, match=r"unknown key\(s\) k1, widht.*no distortion"):
        StereoFolder(folder)
    calib.write_text(text + "baseline: 0.12\n")
    with pytest.raises(DatasetError, match="both baseline and baseline_m"):
        StereoFolder(folder)
