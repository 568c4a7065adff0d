"""A calibration no real stereo camera can have (a focal length of 1e300 px or 0, a principal point far outside
the image, fx and fy a factor 10 apart, a baseline of a kilometre or a nanometre, NaN) is refused when the
dataset is opened, in every loader, with one line naming the file, the value and what is plausible; a
plausible one is read as before."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.datasets import DatasetError, open_dataset
from hippo_nav.datasets.base import BASELINE_M, FIELD_OF_VIEW_DEG, check_calibration
from hippo_nav.datasets.common import rectified_calibration

WIDTH, HEIGHT = 64, 24
GOOD = {"fx": 40.0, "fy": 40.0, "cx": 31.5, "cy": 11.5, "baseline_m": 0.5}
NAN = float("nan")

# (setting, value): each class of implausible value once; the loaders must refuse them all.
BAD = [
    ("fx", 1e300),
    ("fx", 0.0),
    ("fx", -40.0),
    ("fx", NAN),
    ("fx", 1e-3),
    ("fy", 400.0),
    ("fy", 4.0),
    ("cx", 1e5),
    ("cy", -500.0),
    ("baseline_m", 1000.0),
    ("baseline_m", 1e-9),
    ("baseline_m", -0.5),
]


def _images(folder: Path, names: list[str]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    for name in names:
        cv2.imwrite(str(folder / name), rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8))


def write_kitti(root: Path, c: dict[str, float]) -> tuple[Path, Path]:
    seq = root / "sequences" / "00"
    for camera in ("image_0", "image_1"):
        _images(seq / camera, ["000000.png", "000001.png"])
    k = f"{c['fx']!r} 0 {c['cx']!r} {{}} 0 {c['fy']!r} {c['cy']!r} 0 0 0 1 0"
    (seq / "calib.txt").write_text(f"P0: {k.format(0)}\nP1: {k.format(repr(-c['fx'] * c['baseline_m']))}\n")
    (seq / "times.txt").write_text("0.0\n0.1\n")
    return root, seq / "calib.txt"


def write_folder(root: Path, c: dict[str, float]) -> tuple[Path, Path]:
    for side in ("left", "right"):
        _images(root / side, ["1.png", "2.png"])
    (root / "calibration.yaml").write_text("".join(f"{key}: {_yaml(value)}\n" for key, value in c.items()))
    return root, root / "calibration.yaml"


def write_euroc(root: Path, c: dict[str, float]) -> tuple[Path, Path]:
    """Two raw (undistorted) cameras; camera 1 `baseline_m` to the right of camera 0."""
    stamps = [1_000_000_000, 1_050_000_000]
    for name, x_m in (("cam0", 0.0), ("cam1", c["baseline_m"])):
        camera = root / "mav0" / name
        _images(camera / "data", [f"{t}.png" for t in stamps])
        (camera / "data.csv").write_text(
            "#timestamp [ns],filename\n" + "".join(f"{t},{t}.png\n" for t in stamps)
        )
        body_from_sensor = np.eye(4)
        body_from_sensor[0, 3] = x_m
        (camera / "sensor.yaml").write_text(
            "%YAML:1.0\nsensor_type: camera\n"
            f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{', '.join(_yaml(v) for v in body_from_sensor.ravel())}]\n"
            f"resolution: [{WIDTH}, {HEIGHT}]\ncamera_model: pinhole\n"
            f"intrinsics: [{', '.join(_yaml(c[k]) for k in ('fx', 'fy', 'cx', 'cy'))}]\n"
            "distortion_model: radial-tangential\ndistortion_coefficients: [0, 0, 0, 0]\n"
        )
    # Intrinsics are judged per camera file; the baseline once the pair is rectified (both files named).
    return root, root / "mav0" / "cam0" / "sensor.yaml"


def write_rosbag(root: Path, c: dict[str, float]) -> tuple[Path, Path]:
    """A ROS 1 bag of two rectified mono8 pairs; the calibration in the topics YAML."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    types = store.types
    root.mkdir(parents=True)
    bag = root / "pairs.bag"
    image = np.random.default_rng(1).integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8)
    with Writer(bag) as writer:
        for topic in ("/left/image_rect", "/right/image_rect"):
            connection = writer.add_connection(topic, "sensor_msgs/msg/Image", typestore=store)
            for i in range(2):
                t_ns = 1_700_000_000_000_000_000 + i * 100_000_000
                stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
                header = types["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id=topic)
                msg = types["sensor_msgs/msg/Image"](
                    header=header, height=HEIGHT, width=WIDTH, encoding="mono8", is_bigendian=0, step=WIDTH,
                    data=image.reshape(-1),
                )  # fmt: skip
                writer.write(connection, t_ns, store.serialize_ros1(msg, "sensor_msgs/msg/Image"))
    topics = root / "topics.yaml"
    topics.write_text(
        "left_topic: /left/image_rect\nright_topic: /right/image_rect\n"
        + "".join(f"{key}: {_yaml(value)}\n" for key, value in c.items())
    )
    return bag, topics


def _yaml(value: float) -> str:
    return ".nan" if math.isnan(value) else repr(float(value))


LOADERS: dict[str, Callable[[Path, dict[str, float]], tuple[Path, Path]]] = {
    "kitti": write_kitti,
    "folder": write_folder,
    "euroc": write_euroc,
    "rosbag": write_rosbag,
}


def _open(kind: str, path: Path, calibration_file: Path):
    if kind == "rosbag":
        return open_dataset(path, topics=calibration_file)
    return open_dataset(path, sequence="00" if kind == "kitti" else None)


@pytest.mark.parametrize("kind", LOADERS)
def test_a_plausible_calibration_is_read(kind: str, tmp_path: Path) -> None:
    path, calibration_file = LOADERS[kind](tmp_path / kind, GOOD)
    data = _open(kind, path, calibration_file)
    assert data.calibration.image_size_px == (WIDTH, HEIGHT)
    assert data.calibration.baseline_m == pytest.approx(GOOD["baseline_m"], rel=1e-3)
    if kind != "euroc":  # EuRoC's rectification may rescale the focal length a little
        assert (data.calibration.fx, data.calibration.cx) == (GOOD["fx"], GOOD["cx"])


@pytest.mark.parametrize("kind", LOADERS)
@pytest.mark.parametrize(("setting", "value"), BAD, ids=[f"{s}={v:g}" for s, v in BAD])
def test_an_implausible_calibration_is_one_line_naming_file_and_value(
    kind: str, setting: str, value: float, tmp_path: Path
) -> None:
    path, calibration_file = LOADERS[kind](tmp_path / kind, {**GOOD, setting: value})
    with pytest.raises(DatasetError) as caught:
        _open(kind, path, calibration_file)
    message = str(caught.value)
    assert len(message.splitlines()) == 1, message
    named = calibration_file.parent if kind == "euroc" else calibration_file  # cam0 or cam1, or both
    assert str(named) in message, message
    shown = "nan" if math.isnan(value) else f"{value:g}"
    assert shown in message.lower() or (kind == "euroc" and setting == "baseline_m"), message


def test_the_plausible_ranges_are_said() -> None:
    """The message says what would be plausible, so the user can tell a unit error from a typo."""
    with pytest.raises(DatasetError, match=r"calib\.yaml: the stereo baseline is 1000 m; .* 1 mm to 20 m"):
        rectified_calibration(40.0, 40.0, 31.5, 11.5, 1000.0, (WIDTH, HEIGHT), "calib.yaml")
    with pytest.raises(
        DatasetError, match=r"x\.txt: fx = 1e\+300 px gives a horizontal field of view of 0.00°"
    ):
        rectified_calibration(1e300, 1e300, 31.5, 11.5, 0.5, (WIDTH, HEIGHT), "x.txt")
    with pytest.raises(DatasetError, match=r"principal point's cx = 100000 px lies far outside the 64x24"):
        rectified_calibration(40.0, 40.0, 1e5, 11.5, 0.5, (WIDTH, HEIGHT), "x")
    with pytest.raises(DatasetError, match=r"image size 100000x100000 px"):
        rectified_calibration(40.0, 40.0, 31.5, 11.5, 0.5, (100_000, 100_000), "x")
    # The bounds themselves are accepted: a wide-angle and a telephoto camera, a 1 mm and a 20 m rig.
    low_deg, high_deg = FIELD_OF_VIEW_DEG
    for fov_deg in (low_deg * 1.01, high_deg * 0.99):
        fx = WIDTH / (2 * math.tan(math.radians(fov_deg) / 2))
        for baseline_m in (BASELINE_M[0], BASELINE_M[1]):
            c = rectified_calibration(fx, fx, 31.5, 11.5, baseline_m, (WIDTH, HEIGHT), "x")
            assert check_calibration(c, "x") is c
