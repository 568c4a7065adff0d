"""`hippo-nav run --dataset PATH`: every input format runs end to end from the command line (detected by
layout or named by --dataset-kind), and a bad input is one line on stderr with exit code 2."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import as_colour_download
from hippo_nav.cli import main
from hippo_nav.datasets import EurocStereo, KittiOdometry, open_dataset
from hippo_nav.io import read_kitti_poses, write_tum
from hippo_nav.synthetic import loop_trajectory, render_sequence

N_FRAMES = 10
T0_NS = 1_403_636_579_763_555_584


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> KittiOdometry:
    root = render_sequence(
        loop_trajectory(N_FRAMES), tmp_path_factory.mktemp("kitti"), "00", image_size_px=(160, 48)
    )
    return KittiOdometry(root, "00")


@pytest.fixture(scope="module")
def folder(rendered: KittiOdometry, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("folder") / "street"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for frame in rendered:
        cv2.imwrite(str(folder / "left" / f"{frame.index:04d}.png"), frame.left)
        cv2.imwrite(str(folder / "right" / f"{frame.index:04d}.png"), frame.right)
    c = rendered.calibration
    (folder / "calibration.yaml").write_text(
        f"fx: {c.fx}\nfy: {c.fy}\ncx: {c.cx}\ncy: {c.cy}\nbaseline_m: {c.baseline_m}\n"
    )
    write_tum(folder / "ground_truth.tum", rendered.timestamps_s, rendered.ground_truth())
    return folder


def write_euroc(rendered: KittiOdometry, sequence: Path) -> Path:
    """The rendered (rectified) pair as an ASL sequence with an ideal rig: no distortion, no rotation."""
    c = rendered.calibration
    for camera, x_m in (("cam0", 0.0), ("cam1", c.baseline_m)):
        (sequence / "mav0" / camera / "data").mkdir(parents=True)
        body_from_camera = np.eye(4)
        body_from_camera[0, 3] = x_m
        (sequence / "mav0" / camera / "sensor.yaml").write_text(
            f"T_BS:\n  cols: 4\n  rows: 4\n  data: {body_from_camera.ravel().tolist()}\n"
            f"resolution: {list(c.image_size_px)}\ncamera_model: pinhole\n"
            f"intrinsics: [{c.fx}, {c.fy}, {c.cx}, {c.cy}]\n"
            "distortion_model: radial-tangential\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
        )
        rows = ["#timestamp [ns],filename"]
        for frame in rendered:
            stamp = T0_NS + frame.index * 100_000_000
            cv2.imwrite(
                str(sequence / "mav0" / camera / "data" / f"{stamp}.png"),
                frame.left if x_m == 0 else frame.right,
            )
            rows.append(f"{stamp},{stamp}.png")
        (sequence / "mav0" / camera / "data.csv").write_text("\n".join(rows) + "\n")
    return sequence


def run(args: list[str], out: Path) -> dict:
    assert main(["run", *args, "--out", str(out), "--no-progress", "--no-figures"]) == 0
    return json.loads((out / "metrics.json").read_text())


def test_run_on_a_stereo_folder(folder: Path, tmp_path: Path, capsys) -> None:
    metrics = run(["--dataset", str(folder)], tmp_path / "out")
    assert metrics["sequence"] == "street" and metrics["frames"] == N_FRAMES
    # The folder's calibration gives the metric scale: 0.07 m over 13.6 m measured.
    assert metrics["errors"]["vo"]["ate_3d_m"] < 0.02 * metrics["distance_gt_m"]
    assert read_kitti_poses(tmp_path / "out" / "ground_truth.kitti.txt").shape == (N_FRAMES, 4, 4)
    assert "results written" in capsys.readouterr().out


def test_run_on_an_ideal_euroc_rig_and_a_kitti_root(rendered: KittiOdometry, tmp_path: Path) -> None:
    sequence = write_euroc(rendered, tmp_path / "euroc" / "MH_ideal")
    data = EurocStereo(sequence)
    # An ideal rig rectifies to itself: same baseline, the images come back nearly unchanged.
    assert data.calibration.baseline_m == pytest.approx(rendered.calibration.baseline_m)
    assert np.abs(data[3].left[4:-4, 4:-4].astype(float) - rendered[3].left[4:-4, 4:-4]).mean() < 2.0
    metrics = run(
        ["--dataset", str(tmp_path / "euroc"), "--sequence", "MH_ideal", "--stop", "6"], tmp_path / "e"
    )
    assert metrics["sequence"] == "euroc_MH_ideal" and metrics["frames"] == 6
    metrics = run(["--dataset", str(rendered.root), "--sequence", "00", "--stop", "5"], tmp_path / "k")
    assert metrics["frames"] == 5


def test_run_on_kitti_s_colour_download(rendered: KittiOdometry, tmp_path: Path) -> None:
    # The render's pair given as KITTI's colour cameras (image_2, image_3 as colour PNGs; camera 2 6 cm left of
    # camera 0, so P2 and P3 carry that offset): the same images with the same pair geometry, so the VO moves
    # exactly as on the gray pair (camera 2's ground truth: tests/datasets/test_datasets_kitti.py).
    import shutil

    root = tmp_path / "colour"
    shutil.copytree(rendered.root, root)
    seq = root / "sequences" / "00"
    as_colour_download(seq)
    lines = (seq / "calib.txt").read_text().splitlines()
    p0, p1 = (np.array(line.split()[1:], float).reshape(3, 4) for line in lines[:2])
    # The offset (fx · 0.06 m) is rounded to 1/64 px and written in full, so that P2 − P3 is P0 − P1 to the
    # bit: with 12 digits the baseline differed in its 13th, which moved the VO by 2e-5 m in five frames.
    shift_px = np.round(0.06 * p0[0, 0] * 64.0) / 64.0
    p2, p3 = p0.copy(), p1.copy()
    p2[0, 3] += shift_px
    p3[0, 3] += shift_px
    text = "\n".join(
        f"{k}: " + " ".join(f"{v:.17g}" for v in m.ravel())
        for k, m in zip(("P0", "P1", "P2", "P3"), (p0, p1, p2, p3))
    )
    (seq / "calib.txt").write_text(text + "\n")

    gray = run(["--dataset", str(root), "--sequence", "00"], tmp_path / "gray")
    colour = run(["--dataset", str(root), "--sequence", "00", "--cameras", "color"], tmp_path / "color")
    np.testing.assert_array_equal(
        read_kitti_poses(tmp_path / "gray" / "trajectory_vo.kitti.txt"),
        read_kitti_poses(tmp_path / "color" / "trajectory_vo.kitti.txt"),
    )
    assert "image_2, image_3" in colour["note"] and gray["frames"] == colour["frames"] == N_FRAMES


def test_run_on_a_ros_bag_with_topic_flags(rendered: KittiOdometry, tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    Image, Header, Time = (
        store.types[t]
        for t in ("sensor_msgs/msg/Image", "std_msgs/msg/Header", "builtin_interfaces/msg/Time")
    )
    with Writer(tmp_path / "drive", version=9) as bag:
        connections = {t: bag.add_connection(t, Image.__msgtype__, typestore=store) for t in ("/l", "/r")}
        for frame in rendered:
            stamp = 1_700_000_000_000_000_000 + frame.index * 100_000_000
            for topic, image in (("/l", frame.left), ("/r", frame.right)):
                header = Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=topic)
                msg = Image(header=header, height=image.shape[0], width=image.shape[1], encoding="mono8",
                            is_bigendian=0, step=image.shape[1], data=image.reshape(-1))  # fmt: skip
                bag.write(connections[topic], stamp, store.serialize_cdr(msg, Image.__msgtype__))
    c = rendered.calibration
    topics = tmp_path / "topics.yaml"
    topics.write_text(f"fx: {c.fx}\nfy: {c.fy}\ncx: {c.cx}\ncy: {c.cy}\nbaseline_m: {c.baseline_m}\n")
    metrics = run(
        [
            "--dataset",
            str(tmp_path / "drive"),
            "--left-topic",
            "/l",
            "--right-topic",
            "/r",
            "--topics",
            str(topics),
        ],
        tmp_path / "o",
    )
    assert metrics["sequence"] == "drive" and metrics["frames"] == N_FRAMES
    # A topic the bag does not have: one line naming what it has, nothing written.
    code = main(["run", "--dataset", str(tmp_path / "drive"), "--left-topic", "/left", "--right-topic", "/r",
                 "--topics", str(topics), "--out", str(tmp_path / "x"), "--no-progress"])  # fmt: skip
    assert code == 2 and not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("args", "phrase"),
    [
        (["--dataset", "{tmp}/nowhere"], "--dataset {tmp}/nowhere: no such file or folder"),
        (
            ["--dataset", "{folder}", "--left-topic", "/l"],
            "--left-topic: only for ROS bags; {folder} is a folder dataset",
        ),
        (["--dataset-kind", "euroc"], "--dataset-kind needs --dataset PATH"),
        (["--left-topic", "/l", "--right-topic", "/r"], "--left-topic, --right-topic needs --dataset PATH"),
        (
            ["--kitti", "{tmp}", "--dataset", "{folder}"],
            "give one dataset path: --kitti and --dataset name the same",
        ),
        (["--dataset", "{folder}", "--dataset-kind", "euroc"], "not an EuRoC/ASL sequence"),
        (["--dataset", "{tmp}"], "no loader recognises this path"),
        (["--dataset", "{folder}", "--stop", "40"], r"frame range [0, 40) is empty or outside the sequence"),
        (["--dataset", "{folder}", "--cameras", "color"], "--cameras: only for KITTI odometry roots"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(folder: Path, tmp_path: Path, capsys, args, phrase) -> None:
    args = [a.format(tmp=tmp_path, folder=folder) for a in args]
    code = main(["run", *args, "--out", str(tmp_path / "never"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and phrase.format(tmp=tmp_path, folder=folder) in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "never").exists()


def test_open_dataset_detects_each_layout(folder: Path, rendered: KittiOdometry, tmp_path: Path) -> None:
    assert type(open_dataset(folder)).__name__ == "StereoFolder"
    assert type(open_dataset(rendered.root)).__name__ == "KittiOdometry"
    assert type(open_dataset(write_euroc(rendered, tmp_path / "seq"))).__name__ == "EurocStereo"
