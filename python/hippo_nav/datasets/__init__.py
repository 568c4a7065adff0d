"""Stereo datasets: a small protocol (`StereoDataset`) and a registry with one loader file per dataset.

Adding a dataset = one module with a class that implements `StereoDataset`, has a constructor
`Loader(root, sequence, **kw)` and a static `detect(path) -> bool`, plus one line in `LOADERS` below.
`open_dataset(path, sequence)` picks the loader by name (`kind=`) or by detecting the folder layout.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hippo_nav.datasets.base import StereoCalibration, StereoDataset, StereoFrame
from hippo_nav.datasets.kitti import KittiOdometry
from hippo_nav.io.errors import DatasetError

LOADERS: dict[str, type[KittiOdometry]] = {"kitti": KittiOdometry}  # widen to a Union as loaders arrive


def open_dataset(
    path: str | Path, sequence: str = "00", *, kind: str | None = None, **kw: Any
) -> StereoDataset:
    """Open the stereo dataset at `path` (e.g. a KITTI root holding sequences/ and poses/).

    `kind` names a loader in `LOADERS`; without it the layout decides. Extra keywords (start, stop,
    stride, available_only) go to the loader.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: dataset folder not found")
    if kind is not None:
        if kind not in LOADERS:
            raise DatasetError(f"unknown dataset kind {kind!r}; known: {', '.join(sorted(LOADERS))}")
        return LOADERS[kind](path, sequence, **kw)
    for loader in LOADERS.values():
        if loader.detect(path):
            return loader(path, sequence, **kw)
    raise DatasetError(
        f"{path}: no loader recognises this folder (known layouts: {', '.join(sorted(LOADERS))}); "
        "for KITTI pass the folder that holds sequences/ and poses/"
    )


__all__ = [
    "LOADERS",
    "DatasetError",
    "KittiOdometry",
    "StereoCalibration",
    "StereoDataset",
    "StereoFrame",
    "open_dataset",
]
