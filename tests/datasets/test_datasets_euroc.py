"""EuRoC / ASL stereo loader on a synthetic rig with real distortion and a turned right camera.

The street world is rendered through each raw camera (its own K, radial-tangential distortion, pose)
by casting the ray of every distorted pixel, so the loader's OpenCV rectification is checked against
geometry it did not make: rectified rows agree, the baseline is the rig's, the stereo VO on the rectified
frames recovers the known motion, and the ground truth (body poses through T_BS) is camera 0's.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.datasets import DatasetError, EurocStereo, StereoDataset, open_dataset
from hippo_nav.io import quaternion_from_matrix
from hippo_nav.synthetic import StreetWorld, planar_poses
from hippo_nav.vo import run_odometry

SIZE = (320, 96)
RATE_HZ = 10.0
N_FRAMES = 14
GT_RATE_HZ = 100.0
GT_DELAY_S = 0.15  # the ground truth starts after the cameras, like EuRoC's: frames 0 and 1 have none
T0_NS = 1_403_636_579_763_555_584
SPEED_M_S, YAW_RATE_RAD_S = 12.0, 0.25

K0 = np.array([[186.0, 0.0, 161.2], [0.0, 185.4, 46.8], [0.0, 0.0, 1.0]])
K1 = np.array([[184.1, 0.0, 158.3], [0.0, 183.9, 48.9], [0.0, 0.0, 1.0]])
D0 = np.array([-0.09, 0.03, 0.0006, -0.0004])
D1 = np.array([-0.07, 0.02, -0.0005, 0.0003])
FISHEYE_D = (
    np.array([0.02, -0.01, 0.004, -0.001]),
    np.array([0.015, -0.008, 0.003, 0.0]),
)  # equidistant k1..k4
BODY_FROM_CAMERA = np.array(  # camera z forward = body x; camera x right = body −y; camera y down = body −z
    [[0.0, 0.0, 1.0, 0.08], [-1.0, 0.0, 0.0, 0.02], [0.0, -1.0, 0.0, -0.03], [0.0, 0.0, 0.0, 1.0]]
)
WORLD_FROM_KITTI_WORLD = BODY_FROM_CAMERA.copy()  # EuRoC's world is z up; the renderer's y down
WORLD_FROM_KITTI_WORLD[:3, 3] = [4.0, -2.0, 1.5]


def rotation(axis: str, angle_rad: float) -> np.ndarray:
    return cv2.Rodrigues(np.array({"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[axis]) * float(angle_rad))[
        0
    ]


def rig(centre_m=(0.5, 0.012, -0.008), turn_deg=(0.4, 0.9, 0.6)) -> np.ndarray:
    """`camera0_from_camera1`: camera 1 about 0.5 m to the right, slightly turned."""
    pose = np.eye(4)
    rx, ry, rz = np.radians(turn_deg)
    pose[:3, :3] = rotation("x", rx) @ rotation("y", ry) @ rotation("z", rz)
    pose[:3, 3] = centre_m
    return pose


def camera_path(times_s: np.ndarray) -> np.ndarray:
    """Raw camera-0 poses (renderer's world, KITTI axes) on a left curve, pitched down 3° and rolled 1°."""
    yaw = YAW_RATE_RAD_S * times_s
    forward = SPEED_M_S * np.sin(yaw) / YAW_RATE_RAD_S
    left = SPEED_M_S * (1 - np.cos(yaw)) / YAW_RATE_RAD_S
    poses = planar_poses(forward, left, yaw)
    tilt = np.eye(4)
    tilt[:3, :3] = rotation("x", np.radians(-3.0)) @ rotation("z", np.radians(1.0))
    return poses @ tilt


def pixel_rays(K: np.ndarray, D: np.ndarray, model: str = "radial-tangential") -> np.ndarray:
    """(H·W, 3) rays (z = 1) of a distorted camera's pixels, row-major; undistorted to 1e-12."""
    width, height = SIZE
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    undistort = cv2.fisheye.undistortPoints if model == "equidistant" else cv2.undistortPoints
    normalised = undistort(pixels, K, D, R=None, P=None, criteria=criteria).reshape(-1, 2)
    return np.column_stack([normalised, np.ones(len(normalised))])


def render_raw(
    world: StreetWorld, world_from_camera: np.ndarray, K: np.ndarray, rays: np.ndarray
) -> np.ndarray:
    """The distorted image of a camera: the ray of every pixel (`pixel_rays`) cast into the world."""
    width, height = SIZE
    directions = rays @ world_from_camera[:3, :3].T
    hits = world.cast(world_from_camera[:3, 3], directions)
    gray = world.shade(hits, directions, float(K[0, 0]))
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8).reshape(height, width)


def sensor_yaml(
    K: np.ndarray, D: np.ndarray, body_from_sensor: np.ndarray, name: str, model: str = "radial-tangential"
) -> str:
    data = ", ".join(f"{x:.15g}" for x in body_from_sensor.ravel())
    return (
        "%YAML:1.0\n"
        "# General sensor definitions.\n"
        "sensor_type: camera\n"
        f"comment: synthetic {name}\n\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{data}]\n\n"
        f"rate_hz: {RATE_HZ:g}\n"
        f"resolution: [{SIZE[0]}, {SIZE[1]}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{K[0, 0]}, {K[1, 1]}, {K[0, 2]}, {K[1, 2]}] #fu, fv, cu, cv\n"
        f"distortion_model: {model}\n"
        f"distortion_coefficients: [{', '.join(f'{d:.10g}' for d in D)}]\n"
    )


class SyntheticEuroc:
    """What was written: the sequence folder, the frame times, the raw camera-0 poses, the rig."""

    def __init__(
        self,
        root: Path,
        camera0_from_camera1: np.ndarray,
        model: str = "radial-tangential",
        n_frames: int = N_FRAMES,
    ) -> None:
        self.root = root
        self.times_ns = T0_NS + np.arange(n_frames, dtype=np.int64) * int(1e9 / RATE_HZ)
        self.times_s = (self.times_ns - T0_NS) * 1e-9
        self.camera0 = camera_path(self.times_s)
        self.camera0_from_camera1 = camera0_from_camera1
        mav0 = root / "mav0"
        # The street runs on 2.5 s past the last frame: a street end in view would be a poor test scene.
        gt_times_s = np.arange(GT_DELAY_S, self.times_s[-1] + 2.5, 1 / GT_RATE_HZ)
        world = StreetWorld(
            camera_path(gt_times_s)[:, :3, 3], simplify_tolerance_m=0.5
        )  # fewer capsules: faster
        body_from_camera1 = BODY_FROM_CAMERA @ camera0_from_camera1
        distortion = FISHEYE_D if model == "equidistant" else (D0, D1)
        for name, K, D, body_from_sensor in (
            ("cam0", K0, distortion[0], BODY_FROM_CAMERA),
            ("cam1", K1, distortion[1], body_from_camera1),
        ):
            (mav0 / name / "data").mkdir(parents=True)
            (mav0 / name / "sensor.yaml").write_text(sensor_yaml(K, D, body_from_sensor, name, model))
            rows = ["#timestamp [ns],filename"]
            rays = pixel_rays(K, D, model)
            for i, stamp in enumerate(self.times_ns):
                pose = self.camera0[i] if name == "cam0" else self.camera0[i] @ camera0_from_camera1
                cv2.imwrite(str(mav0 / name / "data" / f"{stamp}.png"), render_raw(world, pose, K, rays))
                rows.append(f"{stamp},{stamp}.png")
            (mav0 / name / "data.csv").write_text("\n".join(rows) + "\n")
        # Ground truth: the body (IMU) pose in EuRoC's world, p_RS_R and q_RS_R (w x y z).
        world_from_body = WORLD_FROM_KITTI_WORLD @ camera_path(gt_times_s) @ np.linalg.inv(BODY_FROM_CAMERA)
        lines = [
            "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
        ]
        for t, pose in zip(gt_times_s, world_from_body):
            qx, qy, qz, qw = quaternion_from_matrix(pose[:3, :3])
            x, y, z = pose[:3, 3]
            stamp = T0_NS + round(t * 1e9)
            lines.append(
                f"{stamp},{x:.9f},{y:.9f},{z:.9f},{qw:.12f},{qx:.12f},{qy:.12f},{qz:.12f},0,0,0,0,0,0,0,0,0"
            )
        (mav0 / "state_groundtruth_estimate0").mkdir()
        (mav0 / "state_groundtruth_estimate0" / "data.csv").write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> SyntheticEuroc:
    return SyntheticEuroc(tmp_path_factory.mktemp("euroc") / "MH_synthetic", rig())


@pytest.fixture
def euroc(written: SyntheticEuroc, tmp_path: Path) -> SyntheticEuroc:
    """A private copy of the written sequence, for tests that damage it."""
    copy = SyntheticEuroc.__new__(SyntheticEuroc)
    copy.__dict__.update(written.__dict__)
    copy.root = tmp_path / written.root.name
    shutil.copytree(written.root, copy.root)
    return copy


def test_frames_times_and_rectified_calibration(written: SyntheticEuroc) -> None:
    data = open_dataset(written.root)
    assert isinstance(data, EurocStereo) and isinstance(data, StereoDataset)
    assert data.name == "euroc_MH_synthetic"
    # Frames 0 and 1 precede the ground truth (it starts 0.15 s in) and are left out, with a note.
    assert list(data.frame_indices) == list(range(2, N_FRAMES))
    assert "2 frame(s) outside the ground truth" in data.note
    np.testing.assert_allclose(data.timestamps_s, written.times_ns[2:] * 1e-9)
    calib = data.calibration
    assert calib.image_size_px == SIZE
    assert calib.baseline_m == pytest.approx(np.linalg.norm(written.camera0_from_camera1[:3, 3]), rel=1e-9)
    assert calib.P0[0, 3] == 0 and calib.P1[0, 3] < 0 and calib.P1[1, 3] == pytest.approx(0, abs=1e-9)
    np.testing.assert_allclose(calib.P0[:, :3], calib.P1[:, :3])
    assert 0.8 * K0[0, 0] < calib.fx < 1.3 * K0[0, 0]
    frame = data[0]
    assert frame.index == 2 and frame.left.shape == (SIZE[1], SIZE[0]) and frame.left.dtype == np.uint8
    assert frame.timestamp_s == pytest.approx(written.times_ns[2] * 1e-9)
    # The same sequence opens from mav0/ and from the folder of sequences by name.
    assert len(open_dataset(written.root / "mav0")) == len(data)
    assert len(open_dataset(written.root.parent, written.root.name, kind="euroc")) == len(data)


def rows_agree(frame) -> None:
    """Corners found in the rectified left image lie on the same row in the right one."""
    corners = cv2.goodFeaturesToTrack(frame.left, 300, 0.01, 5).reshape(-1, 2).astype(np.float32)
    guess = corners - [8.0, 0.0]
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(
        frame.left, frame.right, corners, guess.astype(np.float32), winSize=(15, 15), maxLevel=3,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )  # fmt: skip
    ok = status.ravel() == 1
    assert ok.sum() > 50
    row_error = np.abs(tracked[ok, 1] - corners[ok, 1])
    assert np.median(row_error) < 0.15, np.median(row_error)


def test_rectified_rows_agree(written: SyntheticEuroc) -> None:
    rows_agree(EurocStereo(written.root)[3])


def test_equidistant_fisheye_rig(tmp_path: Path) -> None:
    written = SyntheticEuroc(tmp_path / "fisheye", rig(), model="equidistant", n_frames=4)
    data = EurocStereo(written.root)
    assert data.calibration.baseline_m == pytest.approx(np.linalg.norm(written.camera0_from_camera1[:3, 3]))
    np.testing.assert_allclose(
        data.ground_truth()[:, :3, 3], (WORLD_FROM_KITTI_WORLD @ written.camera0[2:])[:, :3, 3], atol=1e-6
    )
    rows_agree(data[1])


def test_vo_on_the_rectified_frames_recovers_the_motion(written: SyntheticEuroc) -> None:
    data = EurocStereo(written.root)
    gt = data.ground_truth()
    assert gt is not None and gt.shape == (len(data), 4, 4)
    truth = np.linalg.inv(gt[0]) @ gt
    estimate, _ = run_odometry(data)
    distance_m = np.linalg.norm(truth[-1, :3, 3])
    assert distance_m > 10
    error_m = np.linalg.norm(estimate[:, :3, 3] - truth[:, :3, 3], axis=1).max()
    assert error_m < 0.02 * distance_m, (error_m, distance_m)
    turn = estimate[-1, :3, :3].T @ truth[-1, :3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1, 1))) < 0.5


def test_ground_truth_is_the_rectified_camera_0(written: SyntheticEuroc) -> None:
    data = EurocStereo(written.root)
    gt = data.ground_truth()
    raw = WORLD_FROM_KITTI_WORLD @ written.camera0[2:]
    # Rectification turns the camera about its centre: the centres are camera 0's …
    np.testing.assert_allclose(gt[:, :3, 3], raw[:, :3, 3], atol=1e-6)
    # … and its x axis runs along the baseline, towards camera 1's centre.
    camera1_centre = (raw @ written.camera0_from_camera1)[:, :3, 3]
    baseline = camera1_centre - raw[:, :3, 3]
    np.testing.assert_allclose(gt[:, :3, 0], baseline / np.linalg.norm(baseline, axis=1)[:, None], atol=1e-6)
    # The rotation that does this is the rectifier's R0.
    np.testing.assert_allclose(
        gt[:, :3, :3], raw[:, :3, :3] @ data.rectifier.rectified_from_camera0.T, atol=1e-6
    )


def test_without_trimming_all_frames_and_no_ground_truth(written: SyntheticEuroc) -> None:
    data = EurocStereo(written.root, trim_to_ground_truth=False, start=1, stride=3)
    assert list(data.frame_indices) == [1, 4, 7, 10, 13]
    assert data.ground_truth() is None and "covers 4 of 5 frames" in data.note


def test_a_frame_one_camera_dropped_is_skipped(euroc: SyntheticEuroc) -> None:
    csv = euroc.root / "mav0" / "cam1" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:6] + lines[7:]) + "\n")  # cam1 loses frame 5
    data = EurocStereo(euroc.root)
    assert 5 not in data.frame_indices and data.missing_frames == [5]
    assert "cam0 lists 14 images and cam1 13" in data.note
    # Timestamps that never match: no pair at all.
    csv.write_text("\n".join(line.replace("1403636", "1403637") for line in lines) + "\n")
    with pytest.raises(DatasetError, match="no frame in .* has both a left and a right image"):
        EurocStereo(euroc.root)


@pytest.mark.parametrize(
    ("camera0_from_camera1", "phrase"),
    [
        (np.eye(4), "at the same place"),
        (rig(centre_m=(0.02, 0.5, 0.0)), "not beside camera 0"),
        (rig(centre_m=(0.0, 0.0, 0.4)), "not beside camera 0"),
        (rig(centre_m=(-0.5, 0.0, 0.0)), "camera 1 is left of camera 0.*swap the two cameras"),
        (rig(turn_deg=(0.0, 50.0, 0.0)), "turned 50° from each other"),
    ],
)
def test_unrectifiable_rigs_are_one_line_errors(euroc: SyntheticEuroc, camera0_from_camera1, phrase) -> None:
    (euroc.root / "mav0" / "cam1" / "sensor.yaml").write_text(
        sensor_yaml(K1, D1, BODY_FROM_CAMERA @ camera0_from_camera1, "cam1")
    )
    with pytest.raises(DatasetError, match=phrase) as error:
        EurocStereo(euroc.root)
    assert "cam0/sensor.yaml" in str(error.value) and "\n" not in str(error.value)


def test_bad_files_are_named(euroc: SyntheticEuroc) -> None:
    mav0 = euroc.root / "mav0"
    sensor = mav0 / "cam0" / "sensor.yaml"
    good = sensor.read_text()
    sensor.write_text(good.replace("intrinsics:", "intrinsic:"))
    with pytest.raises(DatasetError, match=r"cam0/sensor.yaml: no 'intrinsics' key"):
        EurocStereo(euroc.root)
    sensor.write_text(good.replace("radial-tangential", "omni"))
    with pytest.raises(DatasetError, match="distortion model 'omni' is not supported"):
        EurocStereo(euroc.root)
    sensor.write_text(good.replace(f"resolution: [{SIZE[0]}", "resolution: [640"))
    with pytest.raises(
        DatasetError, match=r"cam1/sensor.yaml: resolution \(320, 96\) differs from cam0's \(640"
    ):
        EurocStereo(euroc.root)
    right = mav0 / "cam1" / "sensor.yaml"
    right_good = right.read_text()
    right.write_text(right_good.replace(f"resolution: [{SIZE[0]}", "resolution: [640"))
    with pytest.raises(
        DatasetError, match=r"\.png: size \(320, 96\) differs from the resolution \(640, 96\)"
    ):
        EurocStereo(euroc.root)
    sensor.write_text(good)
    right.write_text(right_good)
    csv = mav0 / "cam0" / "data.csv"
    listing = csv.read_text()
    csv.write_text(listing.replace(",", ";", 2))  # the header line and the first image
    with pytest.raises(DatasetError, match=r"cam0/data.csv:2: expected 'timestamp_ns,filename'"):
        EurocStereo(euroc.root)
    csv.write_text(listing.replace("\n1403", "\n0x1403", 1))
    with pytest.raises(DatasetError, match=r"cam0/data.csv:2: timestamp '0x\d+' is not an integer"):
        EurocStereo(euroc.root)
    csv.write_text(listing)
    shutil.rmtree(mav0 / "cam1")
    with pytest.raises(DatasetError, match="cam1: camera folder missing"):
        EurocStereo(euroc.root)


def test_bad_ground_truth_line(euroc: SyntheticEuroc) -> None:
    gt = euroc.root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = gt.read_text().splitlines()
    fields = lines[3].split(",")
    fields[4] = "2.0"  # q_w: not a unit quaternion
    lines[3] = ",".join(fields)
    gt.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"data.csv:4: the quaternion .* has norm"):
        EurocStereo(euroc.root)
    gt.unlink()
    data = EurocStereo(euroc.root)
    assert data.ground_truth() is None and len(data) == N_FRAMES


def test_not_a_sequence(tmp_path: Path, written: SyntheticEuroc) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="not an EuRoC/ASL sequence"):
        EurocStereo(tmp_path / "empty")
    (tmp_path / "two").mkdir()
    for name in ("A", "B"):
        (tmp_path / "two" / name / "mav0" / "cam0").mkdir(parents=True)
    with pytest.raises(DatasetError, match="holds several ASL sequences; .*: A, B"):
        open_dataset(tmp_path / "two")


def test_timestamps_in_milliseconds_are_refused_not_read_as_frames_100_ns_apart(
    euroc: SyntheticEuroc,
) -> None:
    """data.csv holds nanoseconds; integer milliseconds put the frames 100 ns apart, and the VO rejected every
    step as impossibly fast: a trajectory of zeros, exit 0."""
    for camera in ("cam0", "cam1"):
        csv = euroc.root / "mav0" / camera / "data.csv"
        lines = csv.read_text().splitlines()
        rows = [line.split(",") for line in lines[1:]]
        csv.write_text("\n".join([lines[0]] + [f"{int(t) // 10**6},{name}" for t, name in rows]) + "\n")
    with pytest.raises(
        DatasetError, match=r"cam0/data\.csv: the timestamps advance by a median 1e-07 s.*another unit"
    ):
        EurocStereo(euroc.root)
