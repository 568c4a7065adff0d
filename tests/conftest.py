"""Shared fixtures and helpers. Tests are grouped by area, one folder per package (`engine/`, `map/`,
`view_cells/`, `closure/`, `datasets/`, `vo/`, `pipeline/`, `viewer/`, `cli/`, …); what several areas use
lives here. Real data lives outside the project, at ../shared/data or $HIPPO_NAV_DATA."""

from __future__ import annotations

import os
import shutil
import signal
import threading
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from hippo_nav.datasets import KittiOdometry, StereoFrame
from hippo_nav.pipeline import PipelineConfig, config_from_dict
from hippo_nav.synthetic import DEMO_SEQUENCE, demo_sequence

PROJECT_ROOT = Path(__file__).resolve().parents[1]

QUIET = {"output": {"figures": False}}
"""A config section that skips the figures (most tests check numbers, not pictures)."""


def shared_data_dir() -> Path | None:
    env = os.environ.get("HIPPO_NAV_DATA")
    path = Path(env) if env else PROJECT_ROOT.parent / "shared" / "data"
    return path if path.is_dir() else None


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = shared_data_dir()
    if path is None:
        pytest.skip("real data not found: set HIPPO_NAV_DATA or place it at ../shared/data")
    return path


@pytest.fixture(scope="session")
def demo() -> KittiOdometry:
    """The built-in synthetic demo loop (200 frames, rendered once and cached)."""
    return KittiOdometry(demo_sequence(), DEMO_SEQUENCE)


DEMO_RUN_FRAMES = 60


@pytest.fixture(scope="session")
def demo_results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The results folder of a run over the demo's first `DEMO_RUN_FRAMES` frames, without figures, written
    once per session: read it, never change it (copy what a test alters)."""
    from hippo_nav.cli import main

    out = tmp_path_factory.mktemp("demo_results") / "run"
    assert (
        main(["run", "--out", str(out), "--no-progress", "--no-figures", "--stop", str(DEMO_RUN_FRAMES)]) == 0
    )
    return out


@pytest.fixture
def quiet() -> PipelineConfig:
    """The default config without figures."""
    return config_from_dict(QUIET)


class Frames:
    """The first `n` frames of a dataset, as a `StereoDataset` of its own: optionally with other
    timestamps, a hook called when frame i is loaded (`on_load(i)`, e.g. to raise), and a log of every
    read (`reads`: (frame, reading thread))."""

    def __init__(
        self,
        dataset: KittiOdometry,
        n: int,
        timestamps_s: np.ndarray | None = None,
        on_load: Callable[[int], None] | None = None,
    ) -> None:
        self.d, self.n, self.on_load = dataset, n, on_load
        self.name, self.calibration = dataset.name, dataset.calibration
        self.frame_indices = dataset.frame_indices[:n]
        self.timestamps_s = dataset.timestamps_s[:n] if timestamps_s is None else np.asarray(timestamps_s)
        self.reads: list[tuple[int, int]] = []

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> StereoFrame:
        self.reads.append((i, threading.get_ident()))
        if self.on_load is not None:
            self.on_load(i)
        frame = self.d[i]
        return StereoFrame(frame.index, float(self.timestamps_s[i]), frame.left, frame.right)

    def __iter__(self):
        return (self[i] for i in range(self.n))

    def ground_truth(self) -> np.ndarray | None:
        gt = self.d.ground_truth()
        return None if gt is None else gt[: self.n]


@pytest.fixture(scope="session")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> KittiOdometry:
    """A tiny rendered loop (12 frames of 64×24 pixels) in KITTI layout, for the loaders' tests."""
    from hippo_nav.synthetic import loop_trajectory, render_sequence

    root = render_sequence(
        loop_trajectory(12), tmp_path_factory.mktemp("kitti"), "00", image_size_px=(64, 24)
    )
    return KittiOdometry(root, "00")


@pytest.fixture
def thread_limits_restored(monkeypatch):
    """For tests that call a sweep's `execute_run` in this process: it limits the thread pools of the process
    it runs in (a Ray worker's), here pytest's; they are put back afterwards."""
    # Set to what rayon would take anyway, so the worker's `setdefault` leaves this process's pool as it is.
    default = str(len(os.sched_getaffinity(0)))
    monkeypatch.setenv("RAYON_NUM_THREADS", os.environ.get("RAYON_NUM_THREADS", default))
    threads = cv2.getNumThreads()
    yield
    cv2.setNumThreads(threads)


@pytest.fixture
def disposition():
    """Set a signal's disposition for one test and put the inherited one back afterwards: the tests must not
    depend on how pytest was started (under `nohup` SIGHUP arrives ignored)."""
    inherited = {}

    def set_to(signame: str, handler) -> None:
        number = getattr(signal, signame)
        inherited.setdefault(number, signal.signal(number, handler))

    yield set_to
    for number, handler in inherited.items():
        signal.signal(number, handler)


def as_colour_download(sequence_dir: Path, keep_gray: bool = True) -> None:
    """Write a KITTI sequence folder's gray pair (image_0, image_1) as KITTI's colour download: image_2 and
    image_3 as 3-channel PNGs of the same pixels; without `keep_gray` the gray folders are removed."""
    for gray, colour in (("image_0", "image_2"), ("image_1", "image_3")):
        (sequence_dir / colour).mkdir()
        for path in sorted((sequence_dir / gray).iterdir()):
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(sequence_dir / colour / path.name), cv2.merge([image, image, image]))
        if not keep_gray:
            shutil.rmtree(sequence_dir / gray)
