"""ROS 1 and ROS 2 bags: a rendered synthetic sequence written as image (and CameraInfo) messages with the
`rosbags` writers reads back frame for frame, paired by header stamp, with the recorded or given
calibration; raw images with a recorded K/D/R/P are rectified back; every bad input is a one-line error."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.datasets import DatasetError, KittiOdometry, RosbagStereo, StereoDataset, open_dataset
from hippo_nav.io import write_tum
from hippo_nav.synthetic import loop_trajectory, render_sequence

pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

N_FRAMES = 12  # frames of the shared `rendered` loop (conftest.py)
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"


def stamp_ns(i: int) -> int:
    return T0_NS + i * PERIOD_NS


def projection(calibration, camera: int) -> np.ndarray:
    return (calibration.P0 if camera == 0 else calibration.P1).copy()


class BagWriter:
    """Writes ROS 1 (`version=1`) or ROS 2 bags (2: SQLite, "mcap": MCAP) with the typestore's serialiser."""

    def __init__(self, path: Path, version: int | str) -> None:
        self.version = version
        self.store = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
        storage = StoragePlugin.MCAP if version == "mcap" else StoragePlugin.SQLITE3
        self.writer = Writer1(path) if version == 1 else Writer2(path, version=9, storage_plugin=storage)
        self.connections: dict[str, object] = {}

    def __enter__(self) -> BagWriter:  # noqa: PYI034 - Self needs Python 3.11
        self.writer.open()
        return self

    def __exit__(self, *_) -> None:
        self.writer.close()

    def header(self, t_ns: int, frame_id: str):
        types = self.store.types
        stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        if self.version == 1:
            return types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id)
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def write(self, topic: str, msg, bag_ns: int) -> None:
        msgtype = msg.__msgtype__
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        serialise = self.store.serialize_ros1 if self.version == 1 else self.store.serialize_cdr
        self.writer.write(self.connections[topic], bag_ns, serialise(msg, msgtype))

    def image(self, topic: str, gray: np.ndarray, t_ns: int, encoding: str = "mono8", pad: int = 0) -> None:
        pixels = {
            "mono8": gray,
            "bgr8": cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR),
            "rgb8": cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB),
            "mono16": gray.astype(np.uint16) * 256,
        }[encoding]
        rows = pixels.reshape(pixels.shape[0], -1).view(np.uint8)
        if pad:
            rows = np.hstack([rows, np.zeros((rows.shape[0], pad), np.uint8)])  # row padding: step > width
        msg = self.store.types["sensor_msgs/msg/Image"](
            header=self.header(t_ns, topic), height=gray.shape[0], width=gray.shape[1], encoding=encoding,
            is_bigendian=0, step=rows.shape[1], data=np.ascontiguousarray(rows).reshape(-1),
        )  # fmt: skip
        self.write(topic, msg, t_ns + 5_000_000)  # recorded 5 ms after the exposure: stamps must win

    def compressed(self, topic: str, gray: np.ndarray, t_ns: int) -> None:
        data = np.frombuffer(cv2.imencode(".png", gray)[1].tobytes(), np.uint8)
        msg = self.store.types["sensor_msgs/msg/CompressedImage"](
            header=self.header(t_ns, topic), format="mono8; png compressed", data=data
        )
        self.write(topic, msg, t_ns + 5_000_000)

    def camera_info(self, topic: str, size, K, D, R, P, t_ns: int, model: str = "plumb_bob") -> None:
        types = self.store.types
        roi = types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        arrays = {"d": np.asarray(D, float), "k": np.ravel(K), "r": np.ravel(R), "p": np.ravel(P)}
        if self.version == 1:
            arrays = {k.upper(): v for k, v in arrays.items()}
        msg = types["sensor_msgs/msg/CameraInfo"](
            header=self.header(t_ns, topic), height=size[1], width=size[0], distortion_model=model,
            binning_x=0, binning_y=0, roi=roi, **arrays,
        )  # fmt: skip
        self.write(topic, msg, t_ns)

    def text(self, topic: str, t_ns: int) -> None:
        self.write(topic, self.store.types["std_msgs/msg/String"](data="hello"), t_ns)


def write_bag(
    path: Path,
    version: int | str,
    data: KittiOdometry,
    *,
    info: bool = True,
    right_p: np.ndarray | None = None,
    skip_right: tuple[int, ...] = (),
    left_encoding: str = "mono8",
    compressed_left: bool = False,
) -> Path:
    """The sequence on LEFT/RIGHT (mono8 left, bgr8 right with padded rows), CameraInfo at 1 Hz, chatter."""
    c = data.calibration
    with BagWriter(path, version) as bag:
        for frame in data:
            t = stamp_ns(frame.index)
            if frame.index % 10 == 0 and info:
                for camera, name in ((0, "left"), (1, "right")):
                    p = right_p if camera == 1 and right_p is not None else projection(c, camera)
                    bag.camera_info(
                        f"/stereo/{name}/camera_info", c.image_size_px, c.K, np.zeros(5), np.eye(3), p, t
                    )
            if compressed_left:
                bag.compressed(LEFT, frame.left, t)
            else:
                bag.image(LEFT, frame.left, t, left_encoding)
            if frame.index not in skip_right:
                bag.image(RIGHT, frame.right, t + 1_000_000, "bgr8", pad=3)  # 1 ms later: pairs by time
            bag.text("/chatter", t)
    return path


@pytest.mark.parametrize("version", [1, 2, "mcap"])
def test_reads_back_frames_stamps_and_camera_info(rendered: KittiOdometry, tmp_path: Path, version) -> None:
    path = write_bag(tmp_path / ("run.bag" if version == 1 else "run"), version, rendered)
    with open_dataset(path, left_topic=LEFT, right_topic=RIGHT) as data:
        assert isinstance(data, RosbagStereo) and isinstance(data, StereoDataset)
        assert data.name == "run" and len(data) == N_FRAMES and data.note == ""
        assert data.rectifier is None  # "image_rect": already rectified, P is the calibration
        np.testing.assert_allclose(data.calibration.P0, rendered.calibration.P0)
        np.testing.assert_allclose(data.calibration.P1, rendered.calibration.P1)
        assert data.calibration.baseline_m == pytest.approx(0.537)
        np.testing.assert_allclose(data.timestamps_s, [stamp_ns(i) * 1e-9 for i in range(N_FRAMES)])
        for i in (0, 5, 11):
            frame, truth = data[i], rendered[i]
            assert frame.index == i
            np.testing.assert_array_equal(frame.left, truth.left)
            np.testing.assert_array_equal(frame.right, truth.right)
        assert [f.index for f in data] == list(range(N_FRAMES))
        assert data.ground_truth() is None
    if version != 1:  # a ROS 2 bag also opens by its storage file
        (storage,) = [f for f in path.iterdir() if f.suffix in (".db3", ".mcap")]
        with open_dataset(storage, left_topic=LEFT, right_topic=RIGHT) as data:
            assert data.path == path and len(data) == N_FRAMES


def test_guessed_topics_yaml_calibration_and_ground_truth(rendered: KittiOdometry, tmp_path: Path) -> None:
    path = write_bag(tmp_path / "run", 2, rendered, info=False, compressed_left=True)
    c = rendered.calibration
    stamps_s = np.array([stamp_ns(i) * 1e-9 for i in range(N_FRAMES)])
    write_tum(tmp_path / "gt.tum", stamps_s, rendered.ground_truth())
    topics = tmp_path / "topics.yaml"
    topics.write_text(
        f"fx: {c.fx!r}\nfy: {c.fy!r}\ncx: {c.cx!r}\ncy: {c.cy!r}\nbaseline_m: 0.537\nground_truth: gt.tum\n"
    )
    data = open_dataset(path, topics=topics, start=2, stride=3)
    assert "topics not given; using /stereo/left/image_rect (left) and /stereo/right/image_rect" in data.note
    assert list(data.frame_indices) == [2, 5, 8, 11]
    np.testing.assert_allclose(data.calibration.P1, rendered.calibration.P1, rtol=1e-12)
    np.testing.assert_array_equal(data[1].left, rendered[5].left)  # decoded from PNG
    np.testing.assert_allclose(data.ground_truth(), rendered.ground_truth()[[2, 5, 8, 11]], atol=1e-8)
    # Keywords win over the file: a topic named there that is not in the bag.
    with pytest.raises(DatasetError, match="no topic '/cam0' \\(left\\)"):
        open_dataset(path, topics=topics, left_topic="/cam0", right_topic=RIGHT)


def test_raw_images_are_rectified_with_the_recorded_calibration(tmp_path_factory, tmp_path: Path) -> None:
    """Raw (distorted, turned) images made from a rectified rendering come back as that rendering."""
    root = render_sequence(loop_trajectory(4), tmp_path_factory.mktemp("wide"), "00", image_size_px=(160, 48))
    rectified = KittiOdometry(root, "00")
    c = rectified.calibration
    size = c.image_size_px
    raw_K = [
        np.array([[95.0, 0, 81.0], [0, 94.0, 23.0], [0, 0, 1]]),
        np.array([[93.0, 0, 78.5], [0, 93.5, 24.5], [0, 0, 1]]),
    ]
    raw_D = [np.array([-0.06, 0.01, 0.0004, -0.0003, 0.0]), np.array([-0.05, 0.012, -0.0002, 0.0002, 0.0])]
    turns = [
        cv2.Rodrigues(np.array([0.01, -0.012, 0.004]))[0],
        cv2.Rodrigues(np.array([0.008, 0.015, -0.003]))[0],
    ]
    u, v = np.meshgrid(np.arange(size[0], dtype=np.float64), np.arange(size[1], dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    maps = []
    for camera in (0, 1):  # raw pixel -> where its ray lands in the rectified image
        P = projection(c, camera)
        landed = cv2.undistortPoints(pixels, raw_K[camera], raw_D[camera], R=turns[camera], P=P[:, :3])
        maps.append(landed.reshape(size[1], size[0], 2).astype(np.float32))
    with BagWriter(tmp_path / "raw.bag", 1) as bag:
        for frame in rectified:
            t = stamp_ns(frame.index)
            for camera, name, image in ((0, "left", frame.left), (1, "right", frame.right)):
                raw = cv2.remap(image, maps[camera], None, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
                bag.image(f"/{name}/image_raw", raw, t)
                bag.camera_info(
                    f"/{name}/camera_info",
                    size,
                    raw_K[camera],
                    raw_D[camera],
                    turns[camera],
                    projection(c, camera),
                    t,
                )
    data = open_dataset(tmp_path / "raw.bag", left_topic="/left/image_raw", right_topic="/right/image_raw")
    assert data.rectifier is not None  # "image_raw": rectified with K, D, R, P
    np.testing.assert_allclose(data.calibration.P1, c.P1)
    for i in range(len(data)):
        got, truth = data[i], rectified[i]
        inner = (slice(6, -6), slice(10, -10))
        for a, b in ((got.left, truth.left), (got.right, truth.right)):
            a, b = a[inner].astype(np.float64), b[inner].astype(np.float64)
            assert np.abs(a - b).mean() < 4.0  # two resamplings of a sharp texture
            (dx, dy), _ = cv2.phaseCorrelate(a, b)
            assert np.hypot(dx, dy) < 0.1, (dx, dy)  # no shift: the rectification is the rendered rig's
    # The same images said to be rectified are not: they differ far more.
    as_is = open_dataset(
        tmp_path / "raw.bag", left_topic="/left/image_raw", right_topic="/right/image_raw", rectified=True
    )
    assert np.abs(as_is[0].left[inner].astype(float) - rectified[0].left[inner]).mean() > 8.0


def test_a_dropped_right_image_is_skipped(rendered: KittiOdometry, tmp_path: Path) -> None:
    path = write_bag(tmp_path / "run.bag", 1, rendered, skip_right=(4,))
    data = open_dataset(path, left_topic=LEFT, right_topic=RIGHT)
    assert 4 not in data.frame_indices and data.missing_frames == [4]
    assert "has 12 images and /stereo/right/image_rect 11: 11 pairs matched by header stamp" in data.note
    np.testing.assert_array_equal(data[4].right, rendered[5].right)  # frame 5, paired with its own right


def test_missing_or_wrong_topics_list_what_the_bag_has(rendered: KittiOdometry, tmp_path: Path) -> None:
    path = write_bag(tmp_path / "run.bag", 1, rendered)
    with pytest.raises(
        DatasetError,
        match=r"no topic '/left' \(left\); the bag has: /chatter \(std_msgs/msg/String, 12 msgs\), "
        r"/stereo/left/camera_info .*, /stereo/left/image_rect \(sensor_msgs/msg/Image, 12 msgs\)",
    ) as error:
        open_dataset(path, left_topic="/left", right_topic=RIGHT)
    assert "\n" not in str(error.value)
    with pytest.raises(
        DatasetError, match="topic /chatter \\(right\\) holds std_msgs/msg/String, not sensor_msgs/Image"
    ):
        open_dataset(path, left_topic=LEFT, right_topic="/chatter")
    with pytest.raises(DatasetError, match="left and right topic are the same"):
        open_dataset(path, left_topic=LEFT, right_topic=LEFT)
    with pytest.raises(DatasetError, match="no CameraInfo topic '/info'"):
        open_dataset(path, left_topic=LEFT, right_topic=RIGHT, left_info_topic="/info")
    with pytest.raises(DatasetError, match=r"option\(s\) left_topic do not apply to a kitti dataset"):
        open_dataset(Path(rendered.root), left_topic=LEFT)


@pytest.mark.parametrize(
    ("right_p", "phrase"),
    [
        (np.zeros((3, 4)), "has no projection P \\(a monocular calibration\\)"),
        (np.array([[37.1, 0, 31.5, 0.0], [0, 37.1, 11.5, 0], [0, 0, 1, 0]]), "different intrinsics"),
        ("positive", "P1\\[0,3\\] = .* must be negative"),
        ("vertical", "not horizontal"),
    ],
)
def test_unusable_camera_info_is_an_error(rendered: KittiOdometry, tmp_path: Path, right_p, phrase) -> None:
    if isinstance(right_p, str):
        p = rendered.calibration.P1.copy()
        if right_p == "positive":
            p[0, 3] = -p[0, 3]
        else:
            p[1, 3], p[0, 3] = p[0, 3], 0.0
        right_p = p
    path = write_bag(tmp_path / "run.bag", 1, rendered, right_p=right_p)
    with pytest.raises(DatasetError, match=phrase):
        open_dataset(path, left_topic=LEFT, right_topic=RIGHT)


def test_calibration_and_encoding_errors(rendered: KittiOdometry, tmp_path: Path) -> None:
    bare = write_bag(tmp_path / "bare.bag", 1, rendered, info=False)
    with pytest.raises(DatasetError, match="no calibration: /stereo/left/camera_info is not in the bag"):
        open_dataset(bare, left_topic=LEFT, right_topic=RIGHT)
    with pytest.raises(DatasetError, match="calibration given in part; also give fy, cx, cy, baseline_m"):
        open_dataset(bare, left_topic=LEFT, right_topic=RIGHT, fx=37.0)
    topics = tmp_path / "topics.yaml"
    topics.write_text(f"left_topic: {LEFT}\nright_tpoic: {RIGHT}\n")
    with pytest.raises(DatasetError, match="topics.yaml: unknown key\\(s\\) right_tpoic"):
        open_dataset(bare, topics=topics)
    # `rectified: 'false'` is a non-empty string, true to Python: raw images would go unrectified.
    for text, phrase in (
        (
            f"left_topic: {LEFT}\nright_topic: {RIGHT}\nrectified: 'false'\n",
            "rectified: 'false' is not true or false",
        ),
        (
            f"left_topic: [{LEFT}]\nright_topic: {RIGHT}\n",
            r"left_topic: \['/stereo/left/image_rect'\] is not a name",
        ),
        (
            f"left_topic: {LEFT}\nright_topic: {RIGHT}\nground_truth: true\n",
            "ground_truth: True is not a name",
        ),
    ):
        topics.write_text(text)
        with pytest.raises(DatasetError, match=phrase):
            open_dataset(bare, topics=topics)
    with pytest.raises(DatasetError, match="ROS bag option: rectified: 'no' is not true or false"):
        open_dataset(bare, left_topic=LEFT, right_topic=RIGHT, rectified="no")
    deep = write_bag(tmp_path / "deep.bag", 1, rendered, left_encoding="mono16")
    with pytest.raises(DatasetError, match="image encoding 'mono16' is not supported"):
        open_dataset(deep, left_topic=LEFT, right_topic=RIGHT)
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n garbage")
    with pytest.raises(DatasetError, match="junk.bag: cannot be read as a ROS bag"):
        open_dataset(tmp_path / "junk.bag")


def test_without_rosbags_the_error_says_what_to_install(
    rendered: KittiOdometry, tmp_path: Path, monkeypatch
) -> None:
    path = write_bag(tmp_path / "run.bag", 1, rendered)
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # import fails as if not installed
    with pytest.raises(DatasetError, match=r"needs the rosbags package: pip install 'hippo-nav\[rosbag\]'"):
        open_dataset(path, left_topic=LEFT, right_topic=RIGHT)
