"""The front end's scheduling: the odometry runs `VO_AHEAD` frames ahead of the back end, in frame order,
and frames the caller skips are not measured once it has moved past them."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
from hippo_nav.pipeline.frontend import VO_AHEAD, FrontEnd, OdometryGuard


class _Frames:
    """A dataset of `n` blank frames."""

    def __init__(self, n: int) -> None:
        self.n = n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> SimpleNamespace:
        return SimpleNamespace(index=i, left=np.zeros((4, 4), np.uint8), right=np.zeros((4, 4), np.uint8))


class _Recorder:
    """An odometry that records which frames it measured, in order; it waits on `gate` before each."""

    def __init__(self) -> None:
        self.begun: list[int] = []
        self.measured: list[int] = []
        self.gate = threading.Event()
        self.gate.set()

    def process(self, frame):
        self.begun.append(frame.index)
        self.gate.wait(timeout=10)
        self.measured.append(frame.index)
        return SimpleNamespace(camera_prev_from_camera_cur=np.eye(4), status="ok")


def _settle(frames: list[int], count: int) -> None:
    """Wait (at most 10 s) until `frames` holds `count` frames."""
    deadline = time.monotonic() + 10
    while len(frames) < count and time.monotonic() < deadline:
        time.sleep(0.005)


def test_the_odometry_runs_frames_ahead_of_the_back_end_in_order():
    assert VO_AHEAD >= 2  # more slack than the one frame that left the odometry waiting on the back end
    odometry = _Recorder()
    with FrontEnd(_Frames(10), OdometryGuard(odometry)) as front:
        first = front.get(0)
        _settle(odometry.measured, 1 + VO_AHEAD)
        # While the back end works on frame 0, the odometry has gone on to the next VO_AHEAD frames.
        assert odometry.measured == list(range(1 + VO_AHEAD))
        assert first.frame.index == 0
        results = [front.get(i).frame.index for i in range(1, 10)]
    assert results == list(range(1, 10))
    assert odometry.measured == list(range(10))  # each frame once, in order, never past the end


def test_frames_the_caller_skips_are_not_measured_once_passed():
    odometry = _Recorder()
    with FrontEnd(_Frames(20), OdometryGuard(odometry)) as front:
        front.get(0)
        _settle(odometry.measured, 1 + VO_AHEAD)
        odometry.gate.clear()  # hold the odometry inside its next frame
        front.get(1)  # asks for frame 1 + VO_AHEAD: begun, and held
        _settle(odometry.begun, 2 + VO_AHEAD)
        front.get(2)  # asks for frame 2 + VO_AHEAD: queued behind it
        threading.Timer(1.0, odometry.gate.set).start()
        assert front.get(12).frame.index == 12
    held, queued = 1 + VO_AHEAD, 2 + VO_AHEAD
    assert held in odometry.measured  # begun before the caller moved on: finished
    assert queued not in odometry.measured  # queued and then passed by: never measured
    assert odometry.measured == sorted(odometry.measured)
