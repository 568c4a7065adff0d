"""The camera front end: frames loaded and their odometry measured ahead of the per-frame system.

The odometry plug point: anything with `process(frame) -> step` stands in for the built-in stereo VO
(`Pipeline(..., odometry=)`, or a name in `vo.ODOMETRIES`), where the step has
`camera_prev_from_camera_cur` (4×4 SE(3): the current camera's pose in the previous camera's frame,
identity on the first frame) and `status` ("ok" when the step was measured and trusted, "first" on the
first frame; anything else is flagged). Optional, read by `OdometryExtras.of`: `tracked_pixels` (the
left-image features it tracks, drawn by viewers), `warnings`, `stereo_bias_px` and `stereo_fault` (reported
in `metrics.json`), `disparity_offset_px` (the stereo correction in use after each frame: the closure's
keyframes apply it too), `disparity_offset_frames` (the estimates behind that correction, which a saved memory
keeps with it), `params` (a pydantic model written into `config.json`).

`OdometryGuard` is the odometry's failure policy: an exception or a non-finite step reuses the previous
step (constant-velocity prior) and flags the frame "failed".

`FrontEnd` measures the odometry of the `VO_AHEAD` frames after the back end's (3), and loads one frame
further, each on its own worker thread; the loader also describes the view when the view descriptor asks for
it (`describe_on_worker`). The odometry only looks at images, never at the networks or the map, so frame
k+1's VO (OpenCV releases the interpreter) can run while the networks and the map (Rust, also without the
interpreter) process frame k, and later frames' images are decoded meanwhile (PNG decoding releases it too).
A back end that takes longer than the odometry on some frame (a new vertex, a view to verify) no longer
holds the odometry up: with one frame of slack it waited then; with three, it ran at 1.03× the frame rate on
real KITTI 06 (docs/architecture.md, "Threads").
One loader and one VO worker keep the frames in order, so the results do not depend on the threads, and
only the loader reads the dataset (a bag reader need not be thread-safe). A third thread is the `Worker`
the system hands slow work to (a new vertex's keyframe). The VO worker is the critical path of a frame
(the other stages take less than half its time), so nothing else runs on it: on KITTI-size images a
keyframe extraction averaged 13 ms a frame and a view description 6 ms, which on the VO worker made every
frame that much longer. Without the overlap (`config.overlap_front_end = false`) everything runs on the
calling thread. An error of a later frame (a corrupt image) surfaces when the back end asks for that frame,
after the frames before it are done, as without the overlap.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.datasets.base import StereoDataset, StereoFrame, check_stereo_images
from hippo_nav.io.errors import DatasetError
from hippo_nav.view_cells import ViewDescriptor
from hippo_nav.vo import Odometry, OdometryStep
from hippo_nav.workers import INLINE, Worker

if TYPE_CHECKING:
    from typing_extensions import Self

log = logging.getLogger("hippo_nav.pipeline")
T = TypeVar("T")

# Frames whose odometry is measured ahead of the back end. The back end's time per frame varies (a new
# vertex, a view to verify, a closure) around a mean below the odometry's: with one frame ahead the odometry
# waited whenever the back end took longer than it; a few frames of slack absorb that.
VO_AHEAD = 3

__all__ = [
    "FrontEnd",
    "FrontResult",
    "Odometry",
    "OdometryExtras",
    "OdometryGuard",
    "OdometryStep",
    "resolved_frontend_params",
    "tracked_pixels",
]


def tracked_pixels(odometry: object) -> np.ndarray | None:
    """(n, 2) left-image pixels of the features `odometry` tracks from its last frame, or None when it has
    no `tracked_pixels` (an array, or a method returning one): a replayed or custom odometry."""
    public = getattr(odometry, "tracked_pixels", None)
    pixels = public() if callable(public) else public
    if pixels is None:
        return None
    pixels = np.asarray(pixels, dtype=np.float64)
    return pixels.reshape(-1, 2) if pixels.size % 2 == 0 else None


@dataclass(frozen=True)
class OdometryExtras:
    """The optional attributes of an odometry (module doc), with their defaults: the one place they are read."""

    warnings: list[str] = field(default_factory=list)
    stereo_bias_px: float | None = None
    disparity_offset_px: float | None = None
    stereo_fault: str | None = (
        None  # what is wrong with the stereo pair ("swapped", "unrectified", …), if known
    )
    disparity_offset_frames: int | None = None  # estimates behind `disparity_offset_px`, if it has any

    @classmethod
    def of(cls, odometry: object) -> OdometryExtras:
        bias = getattr(odometry, "stereo_bias_px", None)
        bias_px = None if bias is None or not np.isfinite(bias) else float(bias)
        fault = getattr(odometry, "stereo_fault", None)
        frames = getattr(odometry, "disparity_offset_frames", None)
        return cls(
            list(getattr(odometry, "warnings", [])),
            bias_px,
            disparity_offset_px(odometry),
            None if fault is None else str(fault),
            frames if isinstance(frames, int) and frames >= 0 else None,
        )


def disparity_offset_px(odometry: object) -> float | None:
    """The stereo correction `odometry` applies now (px), or None when it has none (a replayed odometry)."""
    offset = getattr(odometry, "disparity_offset_px", None)
    return None if offset is None or not np.isfinite(offset) else float(offset)


class OdometryGuard:
    """The odometry with its failure policy (module doc): `measure(frame) -> (step, status)`."""

    def __init__(self, odometry: Odometry) -> None:
        self.odometry = odometry
        self._last_step = np.eye(4)

    def measure(self, frame: StereoFrame) -> tuple[np.ndarray, str]:
        """The odometry's SE(3) step, or the previous step (constant-velocity prior) when it fails."""
        try:
            result = self.odometry.process(frame)
            step = np.asarray(result.camera_prev_from_camera_cur, dtype=np.float64)
            status = str(getattr(result, "status", "ok"))
        except DatasetError:
            raise  # the data's fault (a replay with no pose for this frame): it stops the run, as a bad frame does
        except (HippoNavError, ArithmeticError) as err:
            log.warning("frame %s: odometry failed (%s); using the previous step", frame.index, err)
            return self._last_step.copy(), "failed"
        if step.shape != (4, 4) or not np.isfinite(step).all():
            log.warning("frame %s: odometry returned an invalid step; using the previous step", frame.index)
            return self._last_step.copy(), "failed"
        self._last_step = step
        return step, status


class _Loaded(NamedTuple):
    frame: StereoFrame
    load_s: float
    view_description: Any  # None: not made ahead


@dataclass(frozen=True)
class FrontResult:
    """A loaded frame and what the front end measured of it, with the time loading and odometry took."""

    frame: StereoFrame
    step: np.ndarray  # camera_prev_from_camera_cur (after the failure policy)
    vo_status: str
    features_px: np.ndarray | None  # the odometry's tracked features in this frame (None: it has none)
    disparity_offset_px: float | None  # the odometry's stereo correction after this frame (None: none)
    view_description: Any  # the view descriptor's description, when made ahead (None: the system makes it)
    load_s: float
    vo_s: float


class FrontEnd:
    """Loads frames and measures their odometry ahead of the back end (module doc). A context manager:
    the threads run inside `with`; `get(i)` is frame i's `FrontResult`; `worker` takes the system's slow
    work."""

    def __init__(
        self,
        dataset: StereoDataset,
        odometry: OdometryGuard,
        view_cells: ViewDescriptor | None = None,
        overlap: bool = True,
        image_size_px: tuple[int, int] | None = None,
    ) -> None:
        self.dataset = dataset
        # (width, height) every frame's images must have (None: unchecked).
        self._image_size_px = image_size_px
        self.odometry = odometry
        # Views are described on the loader only when the descriptor asks for it (then with the images, ahead).
        self._describe = (
            view_cells.describe if view_cells is not None and view_cells.describe_on_worker else None
        )
        self._overlap = overlap
        self._pool: ThreadPoolExecutor | None = None
        self._loader: ThreadPoolExecutor | None = None
        self._slow: ThreadPoolExecutor | None = None
        self._fronts: dict[int, Future[FrontResult]] = {}  # frames whose odometry is asked for
        self._loads: dict[int, Future[_Loaded]] = {}

    def __enter__(self) -> Self:
        if self._overlap:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hippo-nav-front")
            self._loader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hippo-nav-load")
            self._slow = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hippo-nav-slow")
        return self

    @property
    def worker(self) -> Worker:
        """The slow-work thread (in the order submitted) when overlapping, else `INLINE`."""
        return self if self._slow is not None else INLINE

    def submit(self, work: Callable[..., T], *args: Any) -> Future[T]:
        """Run `work(*args)` on the slow-work thread, after the work already submitted (overlapping only)."""
        if self._slow is None:
            return INLINE.submit(work, *args)
        return self._slow.submit(work, *args)

    def get(self, i: int) -> FrontResult:
        """Frame `i`'s front-end result; starts the odometry of the `VO_AHEAD` frames after it."""
        if self._pool is None:
            return self._front(i)
        for stale in [j for j in self._fronts if j < i]:
            self._fronts.pop(stale).cancel()  # frames skipped by the caller: not measured if not begun
        result = self._fronts.pop(i, None) or self._start(i)
        for j in range(i + 1, min(i + 1 + VO_AHEAD, len(self.dataset))):
            if j not in self._fronts:
                self._fronts[j] = self._start(j)
        return result.result()

    def __exit__(self, *exc: object) -> None:
        # Finish what is queued (the next frame's odometry, keyframes being extracted: a few ms each) so
        # that nothing touches the VO after the run and every vertex gets its keyframe; a frame loaded
        # ahead and never used is dropped.
        for pool in (self._loader, self._pool, self._slow):
            if pool is not None:
                pool.shutdown(wait=True)

    # ----------------------------------------------------------------------------------------------
    def _load(self, i: int) -> _Loaded:
        """Frame `i`, the seconds its loading took, and its view description when made ahead."""
        clock = time.perf_counter()
        frame = self.dataset[i]
        load_s = time.perf_counter() - clock
        # A dataset made in Python can give images its calibration does not describe: that is the data's
        # fault (a `DatasetError`, which stops the run), not a frame the odometry failed on.
        if self._image_size_px is not None:
            check_stereo_images(frame, self._image_size_px)
        return _Loaded(frame, load_s, self._describe(frame) if self._describe is not None else None)

    def _front(self, i: int, loaded: Future[_Loaded] | None = None) -> FrontResult:
        """Load frame `i` (or take it from `loaded`, loaded ahead) and measure its odometry step."""
        frame, load_s, description = self._load(i) if loaded is None else loaded.result()
        clock = time.perf_counter()
        step, vo_status = self.odometry.measure(frame)
        vo_s = time.perf_counter() - clock
        # Read now: with the front end frames ahead, the odometry moves on before the back end is done.
        features_px = tracked_pixels(self.odometry.odometry)
        offset_px = disparity_offset_px(self.odometry.odometry)
        return FrontResult(frame, step, vo_status, features_px, offset_px, description, load_s, vo_s)

    def _loaded(self, i: int) -> Future[_Loaded]:
        """Frame `i` being loaded (asked for now if it was not yet), and frame i+1 asked for."""
        assert self._loader is not None
        for j in (i, i + 1):
            if j < len(self.dataset) and j not in self._loads:
                self._loads[j] = self._loader.submit(self._load, j)
        return self._loads.pop(i)

    def _start(self, i: int) -> Future[FrontResult]:
        assert self._pool is not None
        return self._pool.submit(self._front, i, self._loaded(i))


def resolved_frontend_params(odometry: object, view_cells: object) -> dict[str, Any]:
    """The parameters of the built-in front-end parts with every default filled in (for the resolved config
    written with the results: `vo` with the seed, `views` with the camera's field of view); another part
    keeps its own section as configured."""
    from hippo_nav.view_cells import TemplateViewConfig
    from hippo_nav.vo import VoParams

    resolved = {}
    for section, part, attr, kind in (
        ("vo", odometry, "params", VoParams),
        ("views", view_cells, "config", TemplateViewConfig),
    ):
        params = getattr(part, attr, None)
        if isinstance(params, kind):
            resolved[section] = params.model_dump(mode="json")
    return resolved
