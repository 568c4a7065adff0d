"""What the viewers show, as arrays: the neural panels as images, the decoded bumps, the map and the tracks.

Both viewers (`rerun.py`, `video.py`) draw from these, made from the data of a run's `FrameEvent`s
(`hippo_nav.pipeline.observers`), so the live view, the video and the figures of a run
(`hippo_nav.pipeline.plots`) show the same things the same way:

- Neural panels (the paper's neural-representation figure, `plots.neural_state_figure`): the HD-by-velocity
  ring (θ along x, 0 to 2π; the angular-velocity axis ν along y), the three grid modules' layer-II patterns
  and the CA3 place torus ((θx, θy) on [0, 2π)², θx along x). Unit j of an axis with N units codes
  θ = 2π·j/N. The figures draw them with `origin="lower"`; here they are raster images, so they are flipped
  to keep θy (and ν) increasing upwards. Each is coloured with viridis scaled to its own range, like
  `imshow`'s default. Decoded bumps are pixel positions in those images (pixel centres at +0.5).
- Positions in the map frame (x forward along the initial heading, y left, metres; `hippo_nav.geometry`),
  with the first processed frame as origin for every track, as in `cognitive_map.png`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

from hippo_nav.engine import MODULE_NAMES, SpatialReadout
from hippo_nav.geometry import planar_xy
from hippo_nav.pipeline.observers import FrameEvent, NetworkActivity
from hippo_nav.system.records import FrameRecord
from hippo_nav.view_cells import NO_VIEW_CELL

TWO_PI = 2.0 * np.pi


# viridis as a 256-entry RGB table (OpenCV's), so that colouring a panel is one table look-up.
VIRIDIS_RGB = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)[
    :, 0, ::-1
].copy()


def colorize(activity: np.ndarray) -> np.ndarray:
    """(H, W) activity → (H, W, 3) uint8 RGB, viridis over the array's own range, row 0 at the top holding
    the last row of `activity` (so the array's row axis points up, as the figures' `origin="lower"`)."""
    a = np.asarray(activity, dtype=np.float32)[::-1]
    finite = np.isfinite(a)
    a = a if finite.all() else np.where(finite, a, 0.0)
    low, high = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
    if not high > low:
        return np.broadcast_to(VIRIDIS_RGB[0], a.shape + (3,)).copy()
    index = ((a - low) * (255.0 / (high - low))).astype(np.uint8)
    return VIRIDIS_RGB[index]


def angles_to_pixels(angles_rad: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(n, 2) torus angles (θx, θy) → (n, 2) pixel positions (x, y) in a `colorize`d (height, width) image:
    x = θx/2π·W + 0.5, y = H − 0.5 − θy/2π·H (the image is flipped)."""
    height, width = size
    theta = np.remainder(np.asarray(angles_rad, dtype=np.float64).reshape(-1, 2), TWO_PI)
    return np.column_stack([theta[:, 0] / TWO_PI * width + 0.5, height - 0.5 - theta[:, 1] / TWO_PI * height])


@dataclass(frozen=True)
class NeuralPanel:
    """One network's activity as an image, with the bumps its readout decoded."""

    name: str  # a short identifier: "hd_ring", "layer2_k1", …, "place"
    title: str  # what the figures call it
    label: str  # a short ASCII caption: "HD ring", "grid k=1 layer II", "CA3 place"
    image: np.ndarray | None  # (H, W, 3) uint8 RGB; None when the module is lesioned
    bumps_px: np.ndarray = field(
        default_factory=lambda: np.zeros((0, 2))
    )  # (n, 2) decoded bump centres (x, y)


def neural_panels(network: NetworkActivity, readout: SpatialReadout) -> list[NeuralPanel]:
    """The HD ring, every grid module's layer-II pattern and the place torus (`NetworkActivity`, e.g. a
    `FrameEvent`'s `network`), with the bumps of the `SpatialReadout` (the heading on the ring's middle
    row)."""
    hd = np.asarray(network.hd)
    ring = colorize(hd)
    heading = np.array([[readout.heading_rad, np.pi]])  # θ of the heading; middle of the ν axis
    panels = [
        NeuralPanel("hd_ring", "HD-by-velocity ring", "HD ring", ring, angles_to_pixels(heading, hd.shape))
    ]
    for m, (k, layer2) in enumerate(zip(network.ks, network.layer2)):
        region = f" ({MODULE_NAMES[m]})" if len(network.ks) == len(MODULE_NAMES) else ""
        title = f"grid k={k}{region}: layer II"
        name, label = f"layer2_k{k}", f"grid k={k} layer II"
        if layer2 is None:
            panels.append(NeuralPanel(name, title, label, None))
            continue
        pattern = np.asarray(layer2)
        module = readout.modules[m] if m < len(readout.modules) else None
        bumps = np.array([b.mean_rad for b in module.bumps]) if module is not None and module.bumps else None
        pixels = angles_to_pixels(bumps, pattern.shape) if bumps is not None else np.zeros((0, 2))
        panels.append(NeuralPanel(name, title, label, colorize(pattern), pixels))
    place = np.asarray(network.place)
    bump = readout.place if readout.place is not None else readout.fused
    pixels = (
        angles_to_pixels(np.array([bump.mean_rad]), place.shape) if bump is not None else np.zeros((0, 2))
    )
    panels.append(NeuralPanel("place", "CA3 place torus", "CA3 place", colorize(place), pixels))
    return panels


def bump_table(readout: SpatialReadout, frame_index: int) -> str:
    """The paper's bump table (μ, σ of every grid bump, the fused estimate and the place bump, rad) for one
    readout, in the layout `hippo-nav run` prints and `bump_table.csv` holds."""
    from hippo_nav.pipeline.records import RunRecord
    from hippo_nav.pipeline.results import bump_rows, format_bump_table

    record = RunRecord(snapshots={0: {"frame_index": int(frame_index), "readout": readout}})
    return format_bump_table(bump_rows(record))


def bump_summary(readout: SpatialReadout) -> list[str]:
    """A few lines for a small panel: per grid module the number of bumps and their mean width, then the
    fused estimate and the place bump (μ and σ per axis, rad)."""
    lines = []
    for module in readout.modules:
        if module.lesioned:
            lines.append(f"grid k={module.k}: lesioned")
        elif module.bumps:
            width = float(np.mean([b.width_rad for b in module.bumps]))
            lines.append(f"grid k={module.k}: {len(module.bumps):2d} bumps, sigma {width:.3f}")
        else:
            lines.append(f"grid k={module.k}: no bump")
    for label, bump in (("fused", readout.fused), ("place", readout.place)):
        if bump is None:
            lines.append(f"{label}: none")
        else:
            (mx, my), (sx, sy) = bump.mean_rad, bump.std_rad
            lines.append(f"{label}: mu ({mx:.2f}, {my:.2f}) sigma ({sx:.3f}, {sy:.3f})")
    return lines


# ------------------------------------------------------------------------------------------------
# The camera front end


def view_cell_label(record: FrameRecord) -> str:
    """What the view cells said this frame, e.g. "view cell 12 familiar, injecting 0.62"."""
    if record.view_cell == NO_VIEW_CELL:
        return f"no view cell ({record.view_status})"
    label = f"view cell {record.view_cell} {record.view_status}"
    if record.injection_strength > 0:
        label += f", injecting {record.injection_strength:.2f}"
    return label


# ------------------------------------------------------------------------------------------------
# The map and the tracks


@dataclass(frozen=True)
class MapGraph:
    """The experience map as drawn: vertex positions (N, 2), links (L, 2) as vertex indices, loop flags."""

    vertices_xy: np.ndarray
    links: np.ndarray
    is_loop: np.ndarray

    @classmethod
    def from_export(cls, export: Mapping[str, np.ndarray]) -> MapGraph:
        poses = np.asarray(export["poses"], dtype=np.float64).reshape(-1, 3)
        links = np.asarray(export["links"], dtype=np.int64).reshape(-1, 2)
        is_loop = np.asarray(export["link_is_loop"], dtype=bool).reshape(-1)
        return cls(poses[:, :2], links, is_loop)

    def segments(self, vertices_xy: np.ndarray | None = None) -> np.ndarray:
        """(L, 2, 2) end points of every link (with `vertices_xy`, the links between moved vertices)."""
        xy = self.vertices_xy if vertices_xy is None else vertices_xy
        if len(self.links) == 0:
            return np.zeros((0, 2, 2))
        return np.stack([xy[self.links[:, 0]], xy[self.links[:, 1]]], axis=1)


class Tracks:
    """The map-frame tracks of a run up to the current frame: odometry, the map's online pose, ground truth.

    Filled once per frame by an observer (`update`) into arrays sized for the whole run, so reading the
    tracks so far costs nothing and no observer re-reads the whole record."""

    def __init__(self) -> None:
        self._vo = np.zeros((0, 2))
        self._online = np.zeros((0, 2))
        self._gt_all: np.ndarray | None = None
        self._n = 0

    def update(self, event: FrameEvent) -> None:
        record = event.record
        if self._n == 0:
            self._gt_all = event.run.ground_truth_xy
        if self._n >= len(self._vo):  # sized for the run; grows only if the run's length was unknown
            size = max(event.run.frames, 2 * len(self._vo), self._n + 1)
            self._vo = np.resize(self._vo, (size, 2))
            self._online = np.resize(self._online, (size, 2))
        self._vo[self._n] = planar_xy(np.asarray(record.vo_world_from_camera, dtype=np.float64))
        self._online[self._n] = np.asarray(record.online_pose, dtype=np.float64)[:2]
        self._n += 1

    def __len__(self) -> int:
        return self._n

    @property
    def vo_xy(self) -> np.ndarray:
        return self._vo[: self._n]

    @property
    def online_xy(self) -> np.ndarray:
        return self._online[: self._n]

    @property
    def ground_truth_xy(self) -> np.ndarray | None:
        """Ground truth of the frames processed so far (None without one)."""
        return None if self._gt_all is None else self._gt_all[: self._n]

    @property
    def ground_truth_all_xy(self) -> np.ndarray | None:
        """Ground truth of the whole run (the video scales its map to it from the first frame)."""
        return self._gt_all
