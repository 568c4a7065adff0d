"""Stereo datasets: a small protocol (`StereoDataset`) and a registry with one loader file per dataset.

Adding a dataset = one module with a `StereoLoader` subclass (`base.py`: its class attributes `KIND`,
`TITLE`, `LAYOUT`, `OPTIONS`, `FLAGS`, `DEFAULT_SEQUENCE`, a static `detect(path)`, a constructor
`Loader(root, sequence, **options)` and `_frame(i)`), plus its class in `LOADERS` below; the CLI's
`--dataset-kind` choices, its loader-option flags (each loader's `FLAGS`, in `run` and `sweep`) and its
loader-option checks follow from the registry (docs/architecture.md).
`open_dataset(path, sequence)` picks the loader by name (`kind=`) or by detecting the layout, in the order
of `LOADERS`:

| kind | layout | loader |
|---|---|---|
| kitti | `sequences/XX/image_0,image_1`, `calib.txt`, `times.txt`, `poses/XX.txt` | `KittiOdometry` |
| euroc | `mav0/cam0,cam1/{data.csv,data/,sensor.yaml}`, `state_groundtruth_estimate0/` | `EurocStereo` |
| rosbag | a ROS 1 `.bag` file or a ROS 2 bag folder (`metadata.yaml`) | `RosbagStereo` |
| folder | `left/`, `right/`, `calibration.yaml`, optional `times.txt`, `ground_truth.tum` | `StereoFolder` |
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hippo_nav.datasets.base import (
    DatasetExtras,
    LoaderFlag,
    StereoCalibration,
    StereoDataset,
    StereoFrame,
    StereoLoader,
)
from hippo_nav.datasets.euroc import EurocStereo
from hippo_nav.datasets.folder import StereoFolder
from hippo_nav.datasets.kitti import KittiOdometry
from hippo_nav.datasets.rosbag import RosbagStereo
from hippo_nav.io.errors import DatasetError

LOADERS: dict[str, type[StereoLoader]] = {
    loader.KIND: loader for loader in (KittiOdometry, EurocStereo, RosbagStereo, StereoFolder)
}
"""Loader classes by kind, in detection order."""


def detect_kind(path: str | Path) -> str | None:
    """The kind of the first loader in `LOADERS` that recognises `path`, or None."""
    path = Path(path)
    for kind, loader in LOADERS.items():
        if loader.detect(path):
            return kind
    return None


def open_dataset(
    path: str | Path, sequence: str | None = None, *, kind: str | None = None, **kw: Any
) -> StereoDataset:
    """Open the stereo dataset at `path`: a KITTI root, an EuRoC/ASL sequence, a ROS bag, a stereo folder.

    `sequence` names a KITTI sequence (default: the loader's `DEFAULT_SEQUENCE`, "00" for KITTI) or, for
    EuRoC and folders, a sub-folder of `path`.
    `kind` names a loader in `LOADERS`; without it the layout decides. Extra keywords (start, stop,
    stride, and each loader's own, e.g. `left_topic` for bags) go to the loader; a keyword the loader does
    not take is an error naming it.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: dataset folder not found")
    if kind is not None:
        if kind not in LOADERS:
            raise DatasetError(f"unknown dataset kind {kind!r}; known: {', '.join(sorted(LOADERS))}")
    else:
        kind = detect_kind(path)
        if kind is None:
            layouts = ", ".join(loader.LAYOUT for loader in LOADERS.values())
            raise DatasetError(
                f"{path}: no loader recognises this path (known layouts: {', '.join(LOADERS)}); {layouts}"
            )
    loader = LOADERS[kind]
    options = loader.OPTIONS
    unknown = sorted(k for k, v in kw.items() if k not in options and v is not None)
    if unknown:
        raise DatasetError(
            f"{path}: option(s) {', '.join(unknown)} do not apply to a {kind} dataset "
            f"(it takes {', '.join(options)})"
        )
    kw = {k: v for k, v in kw.items() if k in options}
    sequence = loader.DEFAULT_SEQUENCE if sequence is None else sequence
    # Every registered loader is constructed as `Loader(root, sequence, **options)` (the contract); the base
    # class's own constructor only sets the extras, so the type checker cannot see that signature.
    return loader(path, sequence, **kw)  # type: ignore[call-arg, arg-type]


__all__ = [
    "LOADERS",
    "DatasetError",
    "DatasetExtras",
    "EurocStereo",
    "KittiOdometry",
    "LoaderFlag",
    "RosbagStereo",
    "StereoCalibration",
    "StereoDataset",
    "StereoFolder",
    "StereoFrame",
    "StereoLoader",
    "detect_kind",
    "open_dataset",
]
