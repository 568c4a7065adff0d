"""ROS 1 and ROS 2 bags with a left and a right image topic, read with `rosbags` (no ROS install needed).

`root` is a ROS 1 `.bag` file or a ROS 2 bag folder (holding `metadata.yaml`; its `.db3`/`.mcap` file
works too). What to read comes from keywords or a small YAML file (`topics=`, the CLI's `--topics`);
keywords win over the file:

```yaml
left_topic: /stereo/left/image_rect       # sensor_msgs/Image or sensor_msgs/CompressedImage
right_topic: /stereo/right/image_rect
# calibration, one of:
left_info_topic: /stereo/left/camera_info   # sensor_msgs/CameraInfo (default: <image topic's ns>/camera_info)
right_info_topic: /stereo/right/camera_info
rectified: true        # the images are already rectified (default: true when the topic name holds "rect")
# or, for rectified images without CameraInfo:
fx: 435.2
fy: 435.2
cx: 367.4
cy: 252.2
baseline_m: 0.110
ground_truth: gt.tum   # optional TUM file of camera 0 (relative to this file)
```

Without topics, a bag whose image topics hold exactly one "left" and one "right" (or "cam0"/"cam1")
name is read with those, and `.note` says so. Calibration: fx/fy/cx/cy/baseline_m given → the images are
rectified with that K and baseline. Otherwise the first CameraInfo of each camera: for rectified images
P0 and P1 are the recorded projections (ROS: P_right[0,3] = −f·B); for raw images (`rectified: false`)
the frames are undistorted and rectified with K, D, R, P (what `image_proc` does). A monocular
calibration (P[0,3] = 0 on the right) cannot give depth and is an error.

Pairs are matched by header stamp (within a quarter of the frame interval, or `max_stereo_dt_s`); frame
numbers count the left topic's messages in stamp order. Opening the bag reads every image message once (to
learn the stamps) and keeps the bag open; each frame is then read by its time (`close()` releases it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hippo_nav.datasets.base import (
    LoaderFlag,
    StereoCalibration,
    StereoFrame,
    StereoLoader,
    check_calibration,
)
from hippo_nav.datasets.common import (
    FrameSelection,
    check_increasing,
    check_time_unit,
    decode_image_bytes,
    ground_truth_at_frames,
    pair_by_time,
    read_yaml,
    rectified_calibration,
    to_gray,
    yaml_number,
)
from hippo_nav.datasets.rectify import StereoRectifier, check_projections, rectifier_from_projections
from hippo_nav.io.errors import DatasetError, file_error
from hippo_nav.io.poses import read_tum

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
SETTINGS = (
    "left_topic",
    "right_topic",
    "left_info_topic",
    "right_info_topic",
    "fx",
    "fy",
    "cx",
    "cy",
    "baseline_m",
    "rectified",
    "max_stereo_dt_s",
    "ground_truth",
)
_CHANNELS = {"mono8": 1, "8uc1": 1, "bgr8": 3, "rgb8": 3, "8uc3": 3, "bgra8": 4, "rgba8": 4, "8uc4": 4}
_TO_GRAY = {"rgb8": cv2.COLOR_RGB2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY}
# ROS Bayer names → OpenCV codes (as cv_bridge maps them).
_BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerBG2GRAY,
    "bayer_bggr8": cv2.COLOR_BayerRG2GRAY,
    "bayer_gbrg8": cv2.COLOR_BayerGR2GRAY,
    "bayer_grbg8": cv2.COLOR_BayerGB2GRAY,
}


def bag_path(path: Path) -> Path | None:
    """The path rosbags opens for `path` (a .bag file, a ROS 2 folder, or its storage file), or None."""
    if path.is_file() and path.suffix == ".bag":
        return path
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return None


def decode_image(msg: Any, msgtype: str, where: str) -> np.ndarray:
    """(H, W) uint8 gray of a sensor_msgs Image (mono8, bgr8, rgb8, bgra8, rgba8, bayer_*8) or CompressedImage."""
    if msgtype.endswith("CompressedImage"):
        image = decode_image_bytes(bytes(msg.data), where)
        if image is None:
            raise DatasetError(f"{where}: compressed image ({msg.format!r}) cannot be decoded by OpenCV")
        return to_gray(image, where)
    encoding = str(msg.encoding).lower()
    channels = 1 if encoding in _BAYER else _CHANNELS.get(encoding)
    if channels is None:
        raise DatasetError(
            f"{where}: image encoding {msg.encoding!r} is not supported; record mono8, bgr8, rgb8, bgra8, "
            "rgba8 or bayer_*8 images"
        )
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if height <= 0 or width <= 0 or step < width * channels or data.size < height * step:
        raise DatasetError(
            f"{where}: image data ({data.size} bytes) does not fit {width}x{height}, step {step}, {encoding}"
        )
    rows = data[: height * step].reshape(height, step)[:, : width * channels]
    image = rows.reshape(height, width, channels) if channels > 1 else rows
    if encoding in _BAYER:
        return cv2.cvtColor(np.ascontiguousarray(image), _BAYER[encoding])
    if encoding in _TO_GRAY:
        return cv2.cvtColor(np.ascontiguousarray(image), _TO_GRAY[encoding])
    return to_gray(np.ascontiguousarray(image), where)


def _field(msg: Any, name: str) -> Any:
    """A CameraInfo field by its ROS 2 (k, d, r, p) or ROS 1 (K, D, R, P) name."""
    return getattr(msg, name, None) if hasattr(msg, name) else getattr(msg, name.upper())


def _stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class _Topic:
    """One image topic: its connections, message type, and per message (bag time, ordinal, stamp)."""

    def __init__(self, name: str, info: Any) -> None:
        self.name = name
        self.connections = list(info.connections)
        self.msgtype = str(info.msgtype)
        self.bag_ns: list[int] = []
        self.ordinal: list[int] = []  # among this topic's messages with the same bag time
        self.stamp_ns: list[int] = []


class RosbagStereo(StereoLoader):
    """A stereo pair of image topics in a ROS 1/2 bag as a `StereoDataset` (see the module doc)."""

    KIND = "rosbag"
    TITLE = "ROS bags"
    LAYOUT = "for a ROS bag the .bag file or ROS 2 bag folder"
    OPTIONS = ("start", "stop", "stride", "topics", "trim_to_ground_truth", *SETTINGS)
    FLAGS = (
        LoaderFlag("left_topic", "TOPIC", "left image topic (sensor_msgs/Image) (default: guessed)"),
        LoaderFlag("right_topic", "TOPIC", "right image topic (default: guessed)"),
        LoaderFlag(
            "topics",
            "YAML",
            "YAML with left_topic, right_topic and the calibration (CameraInfo topics, or fx, fy, cx, cy, "
            "baseline_m); flags win over it (default: none)",
        ),
    )

    def __init__(
        self,
        root: str | Path,
        sequence: str | None = None,
        start: int | None = None,
        stop: int | None = None,
        stride: int = 1,
        *,
        topics: str | Path | None = None,
        trim_to_ground_truth: bool = True,
        **settings: Any,
    ) -> None:
        super().__init__(stride)
        self._reader: Any = None
        path = Path(root)
        opened = bag_path(path)
        if opened is None:
            raise DatasetError(
                f"{path}: not a ROS bag (a ROS 1 .bag file, or a ROS 2 folder with metadata.yaml)"
            )
        if sequence:
            raise DatasetError(f"{path}: a bag holds one sequence; drop the sequence ({sequence!r})")
        self.path = opened
        self.name = opened.stem if opened.is_file() else opened.name
        config = self._settings(topics, settings)
        # Where fx, fy, cx, cy and baseline_m came from, for the message when they are implausible.
        from_options = any(settings.get(k) is not None for k in ("fx", "fy", "cx", "cy", "baseline_m"))
        self._calibration_source = (
            f"{opened} (the fx, fy, cx, cy, baseline_m options)"
            if from_options or topics is None
            else str(topics)
        )

        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise DatasetError(
                "reading ROS bags needs the rosbags package: pip install 'hippo-nav[rosbag]' (or rosbags)"
            ) from None
        store = getattr(Stores, "LATEST", None) or Stores.ROS2_HUMBLE
        try:
            self._reader = AnyReader([opened], default_typestore=get_typestore(store))
            self._reader.open()
        except Exception as err:  # noqa: BLE001 - rosbags raises its own error classes per storage format
            self._reader = None
            raise DatasetError(f"{opened}: cannot be read as a ROS bag ({err})") from None

        try:
            self._load(config, start, stop, stride, trim_to_ground_truth)
        except BaseException:
            self.close()  # a bad bag is reported now; do not keep it open
            raise

    def _load(
        self, config: dict[str, Any], start: int | None, stop: int | None, stride: int, trim: bool
    ) -> None:
        opened = self.path
        # Topics: given or recognised by name; both must be image topics.
        available = self._reader.topics
        left_name, right_name = self._image_topics(config, available)
        self._left, self._right = (
            _Topic(left_name, available[left_name]),
            _Topic(right_name, available[right_name]),
        )
        self._scan()

        # Stereo pairs by header stamp, then the frame range.
        left_s, right_s = (np.array(t.stamp_ns, dtype=np.float64) * 1e-9 for t in (self._left, self._right))
        check_increasing(left_s, f"{opened} {left_name}")
        left_idx, right_idx, _ = pair_by_time(left_s, right_s, config.get("max_stereo_dt_s"))
        if len(left_idx) < max(len(left_s), len(right_s)):
            self.warnings.append(
                f"{left_name} has {len(left_s)} images and {right_name} {len(right_s)}: {len(left_idx)} pairs "
                "matched by header stamp, the other images are not used"
            )
        selection = FrameSelection(left_idx, len(left_s), start, stop, stride, f"{opened} {left_name}")
        self.missing_frames = selection.missing_frames
        self.warnings += selection.warnings
        partner = dict(zip(left_idx.tolist(), right_idx.tolist()))
        frames = selection.frames
        times_s = left_s[frames]
        check_time_unit(f"{opened} {left_name}", frames, times_s)

        # Calibration (and rectification), checked on the first pair.
        self.rectifier: StereoRectifier | None = None
        first_left = self._image(self._left, int(frames[0]))
        size = (first_left.shape[1], first_left.shape[0])
        self.calibration = self._calibration(config, available, size)

        if config.get("ground_truth"):
            gt_path = Path(config["ground_truth"])
            gt_s, gt_poses = read_tum(gt_path)
            check_increasing(gt_s, str(gt_path))
            gt, keep, notes = ground_truth_at_frames(gt_s, gt_poses, times_s, trim, str(gt_path))
            self.warnings += notes
            frames, times_s, self._ground_truth = frames[keep], times_s[keep], gt
        self.frame_indices = frames
        self.timestamps_s = times_s
        self._right_of = np.array([partner[int(f)] for f in frames], dtype=np.int64)
        self[0]  # decodes (and rectifies) the first pair now: an unsupported encoding fails here
        self._finish_note()

    # ----------------------------------------------------------------------------------------------
    @staticmethod
    def _settings(topics: str | Path | None, given: dict[str, Any]) -> dict[str, Any]:
        unknown = sorted(set(given) - set(SETTINGS))
        if unknown:
            raise DatasetError(
                f"unknown ROS bag option(s) {', '.join(unknown)}; known: {', '.join(SETTINGS)}"
            )
        config: dict[str, Any] = {}
        if topics is not None:
            topics_path = Path(topics)
            config = read_yaml(topics_path, "topics file (left_topic, right_topic, …)")
            unknown = sorted(set(config) - set(SETTINGS))
            if unknown:
                raise file_error(
                    topics_path, f"unknown key(s) {', '.join(unknown)}; known: {', '.join(SETTINGS)}"
                )
            _check_setting_types(config, str(topics_path))
            if config.get("ground_truth"):
                config["ground_truth"] = str(topics_path.parent / str(config["ground_truth"]))
            for key in ("fx", "fy", "cx", "cy", "baseline_m", "max_stereo_dt_s"):
                if config.get(key) is not None:
                    config[key] = yaml_number(config, key, topics_path, positive=key != "cx" and key != "cy")
        given = {k: v for k, v in given.items() if v is not None}
        _check_setting_types(given, "ROS bag option")
        config.update(given)
        return config

    def _describe(self, available: dict[str, Any]) -> str:
        return ", ".join(
            f"{name} ({info.msgtype}, {info.msgcount} msgs)" for name, info in sorted(available.items())
        )

    def _image_topics(self, config: dict[str, Any], available: dict[str, Any]) -> tuple[str, str]:
        left, right = config.get("left_topic"), config.get("right_topic")
        images = sorted(name for name, info in available.items() if info.msgtype in IMAGE_TYPES)
        if left is None and right is None:
            for a, b in (("left", "right"), ("cam0", "cam1")):
                lefts = [t for t in images if a in t.lower()]
                rights = [t for t in images if b in t.lower()]
                if len(lefts) == 1 and len(rights) == 1:
                    left, right = lefts[0], rights[0]
                    self.warnings.append(f"topics not given; using {left} (left) and {right} (right)")
                    break
            else:
                raise DatasetError(
                    f"{self.path}: give left_topic and right_topic (--left-topic/--right-topic or --topics "
                    f"YAML); image topics in the bag: {', '.join(images) or 'none'}"
                )
        for role, topic in (("left", left), ("right", right)):
            if topic is None:
                raise DatasetError(
                    f"{self.path}: {role}_topic not given; image topics in the bag: {', '.join(images)}"
                )
            if topic not in available:
                raise DatasetError(
                    f"{self.path}: no topic {topic!r} ({role}); the bag has: {self._describe(available)}"
                )
            if available[topic].msgtype not in IMAGE_TYPES:
                raise DatasetError(
                    f"{self.path}: topic {topic} ({role}) holds {available[topic].msgtype}, not "
                    "sensor_msgs/Image or CompressedImage"
                )
        if left == right:
            raise DatasetError(f"{self.path}: left and right topic are the same ({left}); give two topics")
        return str(left), str(right)

    def _scan(self) -> None:
        """One pass over both image topics: bag time and header stamp of every message."""
        by_connection = {}
        for topic in (self._left, self._right):
            for connection in topic.connections:
                by_connection[connection.id] = topic
        last: dict[str, tuple[int, int]] = {}
        connections = self._left.connections + self._right.connections
        for connection, bag_ns, raw in self._reader.messages(connections=connections):
            topic = by_connection[connection.id]
            msg = self._reader.deserialize(raw, connection.msgtype)
            previous_ns, count = last.get(topic.name, (-1, 0))
            ordinal = count + 1 if previous_ns == bag_ns else 0
            last[topic.name] = (bag_ns, ordinal)
            topic.bag_ns.append(int(bag_ns))
            topic.ordinal.append(ordinal)
            topic.stamp_ns.append(_stamp_ns(msg))
        for topic in (self._left, self._right):
            if not topic.stamp_ns:
                raise DatasetError(f"{self.path}: topic {topic.name} holds no messages")
            if not any(topic.stamp_ns):
                topic.stamp_ns = list(topic.bag_ns)
                self.warnings.append(
                    f"{topic.name}: header stamps are all zero; using the bag's record times"
                )
            order = np.argsort(np.array(topic.stamp_ns), kind="stable")
            for attribute in ("bag_ns", "ordinal", "stamp_ns"):
                values = getattr(topic, attribute)
                setattr(topic, attribute, [values[k] for k in order])

    def _message(self, topic: _Topic, k: int) -> tuple[Any, str]:
        bag_ns, ordinal = topic.bag_ns[k], topic.ordinal[k]
        at_time = self._reader.messages(connections=topic.connections, start=bag_ns, stop=bag_ns + 1)
        for found, (connection, _, raw) in enumerate(at_time):
            if found == ordinal:
                return self._reader.deserialize(raw, connection.msgtype), connection.msgtype
        raise DatasetError(f"{self.path}: message {k} of {topic.name} (bag time {bag_ns} ns) is gone")

    def _image(self, topic: _Topic, k: int) -> np.ndarray:
        if self._reader is None:
            raise DatasetError(f"{self.path}: the bag was closed; open the dataset again")
        msg, msgtype = self._message(topic, k)
        return decode_image(msg, msgtype, f"{self.path} {topic.name} (stamp {topic.stamp_ns[k]} ns)")

    def _first_info(self, topic: str, available: dict[str, Any]) -> Any:
        if topic not in available:
            raise DatasetError(
                f"{self.path}: no CameraInfo topic {topic!r}; the bag has: {self._describe(available)}"
            )
        info = available[topic]
        if info.msgtype != INFO_TYPE:
            raise DatasetError(f"{self.path}: topic {topic} holds {info.msgtype}, not sensor_msgs/CameraInfo")
        for connection, _, raw in self._reader.messages(connections=info.connections):
            return self._reader.deserialize(raw, connection.msgtype)
        raise DatasetError(f"{self.path}: CameraInfo topic {topic} holds no messages")

    def _calibration(
        self, config: dict[str, Any], available: dict[str, Any], size: tuple[int, int]
    ) -> StereoCalibration:
        direct = [k for k in ("fx", "fy", "cx", "cy", "baseline_m") if config.get(k) is not None]
        if direct:
            missing = [k for k in ("fx", "fy", "cx", "cy", "baseline_m") if config.get(k) is None]
            if missing:
                raise DatasetError(f"{self.path}: calibration given in part; also give {', '.join(missing)}")
            fx, fy, cx, cy, baseline_m = (float(config[k]) for k in ("fx", "fy", "cx", "cy", "baseline_m"))
            if config.get("rectified") is False:
                raise DatasetError(
                    f"{self.path}: fx/fy/cx/cy/baseline_m describe rectified images; drop rectified: false"
                )
            return rectified_calibration(fx, fy, cx, cy, baseline_m, size, self._calibration_source)

        infos = []
        for role, image_topic in (("left", self._left.name), ("right", self._right.name)):
            topic = config.get(f"{role}_info_topic") or image_topic.rsplit("/", 1)[0] + "/camera_info"
            if topic not in available and not config.get(f"{role}_info_topic"):
                raise DatasetError(
                    f"{self.path}: no calibration: {topic} is not in the bag; give left_info_topic/"
                    "right_info_topic (CameraInfo) or fx, fy, cx, cy, baseline_m in the topics YAML"
                )
            infos.append((topic, self._first_info(topic, available)))
        where = f"{self.path} {infos[0][0]} + {infos[1][0]}"
        cameras = []
        for topic, msg in infos:
            if (int(msg.width), int(msg.height)) not in (size, (0, 0)):
                raise DatasetError(
                    f"{self.path}: {topic} is for {msg.width}x{msg.height} images but the images are "
                    f"{size[0]}x{size[1]}"
                )
            P = np.asarray(_field(msg, "p"), dtype=np.float64).reshape(3, 4)
            if not np.any(P):
                raise DatasetError(
                    f"{self.path}: {topic} has no projection P (a monocular calibration); calibrate the pair as "
                    "stereo, or give fx, fy, cx, cy, baseline_m"
                )
            K = np.asarray(_field(msg, "k"), dtype=np.float64).reshape(3, 3)
            R = np.asarray(_field(msg, "r"), dtype=np.float64).reshape(3, 3)
            D = np.asarray(_field(msg, "d"), dtype=np.float64).reshape(-1)
            cameras.append((K, D, R if np.any(R) else np.eye(3), P, str(msg.distortion_model)))
        rectified = config.get("rectified")
        if rectified is None:
            rectified = "rect" in self._left.name.lower() and "rect" in self._right.name.lower()
        if rectified:
            p0, p1 = cameras[0][3], cameras[1][3]
            check_projections(p0, p1, where)
            return check_calibration(StereoCalibration(p0.copy(), p1.copy(), None, None, size), where)
        self.rectifier = rectifier_from_projections(tuple(c[:4] for c in cameras), size, cameras[0][4], where)
        return self.rectifier.calibration

    # ----------------------------------------------------------------------------------------------
    def _frame(self, i: int) -> StereoFrame:
        frame = int(self.frame_indices[i])
        left = self._image(self._left, frame)
        right = self._image(self._right, int(self._right_of[i]))
        expected = self.calibration.image_size_px
        for topic, image in ((self._left.name, left), (self._right.name, right)):
            if (image.shape[1], image.shape[0]) != expected:
                raise DatasetError(
                    f"{self.path}: {topic} image of frame {frame} is {image.shape[1]}x{image.shape[0]}, "
                    f"not {expected[0]}x{expected[1]} like the first left image"
                )
        if self.rectifier is not None:
            left, right = self.rectifier(left, right)
        return StereoFrame(frame, float(self.timestamps_s[i]), left, right)

    def close(self) -> None:
        """Release the bag (frames cannot be read afterwards)."""
        if self._reader is not None:
            reader, self._reader = self._reader, None
            reader.close()

    def __enter__(self) -> RosbagStereo:  # noqa: PYI034 - Self needs Python 3.11
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001, S110 - at interpreter shutdown there is nothing to report to
            pass

    @staticmethod
    def detect(path: Path) -> bool:
        """True for a ROS 1 .bag file or a ROS 2 bag folder (or its .db3/.mcap file)."""
        return bag_path(path) is not None

    def __repr__(self) -> str:
        return f"RosbagStereo(path={str(self.path)!r}, topics=({self._left.name}, {self._right.name}), frames={len(self)})"


def _check_setting_types(settings: dict[str, Any], where: str) -> None:
    """A topic or file name must be text and `rectified` a boolean: `rectified: 'false'` is a non-empty
    string, which would read as true and skip the rectification of raw images."""
    for key in ("left_topic", "right_topic", "left_info_topic", "right_info_topic", "ground_truth"):
        if settings.get(key) is not None and not isinstance(settings[key], str | Path):
            raise DatasetError(f"{where}: {key}: {settings[key]!r} is not a name; give one as text")
    if settings.get("rectified") is not None and not isinstance(settings["rectified"], bool):
        raise DatasetError(f"{where}: rectified: {settings['rectified']!r} is not true or false (unquoted)")
