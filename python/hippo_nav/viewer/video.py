"""A video of the mapping, like the paper's: camera, neural panels and the cognitive map growing.

`VideoObserver(path, every=5)` with `Pipeline(..., observers=[...])`, or `hippo-nav run --video` (written as
`mapping.mp4` in the results folder). One video frame every `every` camera frames (run positions 0, every,
2·every, …), plus a last one after the run's final correction, which also shows the corrected map and track;
so a run of n frames gives `len(range(0, n, every)) + 1` video frames. MPEG-4 ('mp4v') through OpenCV's
`VideoWriter`: no codec beyond what opencv-python ships.

Each frame is one 1280×720 canvas drawn with OpenCV (no matplotlib: it would cost more than the pipeline):

- left: the left camera image with the features the odometry tracks and the view-cell template's rows
  (labelled with the active view cell); the HD-by-velocity ring (θ 0–360° along x, the heading marked); the
  three layer-II patterns and the CA3 place torus with their decoded bumps (`panels.neural_panels`, as in
  `neural_state_*.png`); the decoded heading, yaw rate and speed, and a short bump table.
- right: the cognitive map so far — ground truth (wide, light grey), odometry (orange), the map's online
  track (blue), odometric links (grey), loop links (red), vertices (green), the agent (black) — with x
  forward and y (left) up, on a scale that only ever grows (the whole ground truth from the first frame).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from hippo_nav.geometry import planar_xy
from hippo_nav.io.atomic import open_atomic
from hippo_nav.pipeline.observers import FrameEvent
from hippo_nav.pipeline.records import RunResult
from hippo_nav.viewer.panels import (
    MapGraph,
    NeuralPanel,
    Tracks,
    bump_summary,
    neural_panels,
    view_cell_label,
)

CANVAS_SIZE_PX = (1280, 720)  # width, height
FOURCC = "mp4v"
VIDEO_NAME = "mapping.mp4"  # the name OpenCV writes under, in a private folder
FONT = cv2.FONT_HERSHEY_SIMPLEX
# BGR colours, as in cognitive_map.png.
WHITE, BLACK, TEXT = (255, 255, 255), (0, 0, 0), (40, 40, 40)
GT, ODOMETRY, ONLINE, CORRECTED = (200, 200, 200), (14, 127, 255), (180, 119, 31), (189, 103, 148)
LINK, LOOP, VERTEX, FEATURE, BUMP = (150, 150, 150), (0, 0, 220), (44, 160, 44), (0, 230, 0), (60, 60, 255)


class VideoObserver:
    """Writes the mapping video (module doc). `path`: the .mp4 to write (opened at the first frame, so that
    the results folder it lives in can be checked and created by the pipeline first); `every`: camera
    frames per video frame; `fps`: video frames per second."""

    def __init__(self, path: str | Path, every: int = 5, fps: float = 10.0) -> None:
        from hippo_nav._core import HippoNavError

        if int(every) < 1:
            raise HippoNavError(f"video: every={every}; give a positive number of frames per video frame")
        if not fps > 0:
            raise HippoNavError(f"video: fps={fps}; give a positive frame rate")
        self.path = Path(path)
        self.every = int(every)
        self.fps = float(fps)
        self.frames_written = 0
        self._writer: cv2.VideoWriter | None = None
        self._staging: tempfile.TemporaryDirectory | None = None
        self._tracks = Tracks()
        self._position = 0
        self._last: FrameEvent | None = None
        self._bounds: np.ndarray | None = (
            None  # (2, 2) map extent drawn so far: [[x_min, y_min], [x_max, y_max]]
        )
        _check_codec()

    # ----------------------------------------------------------------------------------------------
    def on_frame(self, event: FrameEvent) -> None:
        self._tracks.update(event)
        self._last = event
        if self._position % self.every == 0:
            self._write(self.render(event))
        self._position += 1

    def on_finish(self, result: RunResult) -> None:
        """A last frame after the final correction, then the file is closed."""
        try:
            if self._last is not None:
                self._write(self.render(self._last, result=result))
        finally:
            self.close()

    def close(self) -> None:
        """Finish the file and put it in place (an unfinished MPEG-4 file is unplayable, so the video is
        written in a private temporary folder and appears at `path` only whole)."""
        if self._writer is None:
            return
        self._writer.release()
        self._writer = None
        staging, self._staging = self._staging, None
        if staging is None:
            return
        try:
            with open_atomic(self.path, "wb") as f, (Path(staging.name) / VIDEO_NAME).open("rb") as src:
                shutil.copyfileobj(src, f)
        finally:
            staging.cleanup()

    # ----------------------------------------------------------------------------------------------
    def render(self, event: FrameEvent, result: RunResult | None = None) -> np.ndarray:
        """The (720, 1280, 3) BGR canvas of one frame (`result`: the final one, with the corrected map)."""
        record = event.record
        width, height = CANVAS_SIZE_PX
        canvas = np.full((height, width, 3), 255, np.uint8)
        title = f"hippo_nav: {event.run.name}   frame {record.frame_index}"
        title += f"   t = {record.timestamp_s:.1f} s" + (
            "   (final correction)" if result is not None else ""
        )
        _text(canvas, title, (10, 20), scale=0.55)
        _draw_camera(canvas, event, (10, 30, 620, 200))
        y = _draw_neural(canvas, neural_panels(event.network, event.readout), (10, 240, 620))
        _draw_readout(canvas, event, (10, y + 12))
        self._draw_map(canvas, event, result, (650, 30, 620, 680))
        return canvas

    def _write(self, canvas: np.ndarray) -> None:
        if self._writer is None:
            from hippo_nav._core import HippoNavError

            self.path.parent.mkdir(parents=True, exist_ok=True)
            # OpenCV takes the name as a C string (a name that is not UTF-8 crashes it), so it writes
            # under a plain name in a private folder; `close` moves the finished file into place.
            staging = tempfile.TemporaryDirectory(prefix="hippo_nav_video_")
            writer = cv2.VideoWriter(
                str(Path(staging.name) / VIDEO_NAME),
                cv2.VideoWriter.fourcc(*FOURCC),
                self.fps,
                CANVAS_SIZE_PX,
            )
            if not writer.isOpened():
                staging.cleanup()
                raise HippoNavError(f"cannot write the video {self.path} (OpenCV's VideoWriter refused it)")
            self._writer, self._staging = writer, staging
        self._writer.write(canvas)
        self.frames_written += 1

    def _draw_map(self, canvas: np.ndarray, event: FrameEvent, result: RunResult | None, box: tuple) -> None:
        x0, y0, w, h = box
        record = event.record
        graph = MapGraph.from_export(result.map_export if result is not None else event.map_export)
        tracks = self._tracks
        layers = [tracks.vo_xy, tracks.online_xy, graph.vertices_xy]
        if tracks.ground_truth_all_xy is not None:
            layers.append(tracks.ground_truth_all_xy)
        corrected = None
        if result is not None:
            corrected = planar_xy(result.corrected_world_from_camera)
            layers.append(corrected)
        points = np.concatenate([p for p in layers if len(p)])
        points = points[np.isfinite(points).all(axis=1)]
        if len(points):
            extent = np.array([points.min(axis=0), points.max(axis=0)])
            if self._bounds is None:
                self._bounds = extent
            else:  # only ever grows: the map does not jump about from one video frame to the next
                self._bounds = np.array(
                    [np.minimum(self._bounds[0], extent[0]), np.maximum(self._bounds[1], extent[1])]
                )
        bounds = self._bounds if self._bounds is not None else np.array([[-10.0, -10.0], [10.0, 10.0]])
        span = np.maximum(bounds[1] - bounds[0], 20.0)
        scale = 0.92 * min(w / span[0], h / span[1])
        centre = bounds.mean(axis=0)

        def to_px(xy: np.ndarray) -> np.ndarray:
            xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
            u = x0 + w / 2 + (xy[:, 0] - centre[0]) * scale
            v = y0 + h / 2 - (xy[:, 1] - centre[1]) * scale
            return np.column_stack([u, v])

        cv2.rectangle(canvas, (x0, y0), (x0 + w, y0 + h), (220, 220, 220), 1)
        n_loops = int(graph.is_loop.sum())
        caption = (
            f"cognitive map: {len(graph.vertices_xy)} vertices, {len(graph.links)} links ({n_loops} loop)"
        )
        _text(canvas, caption + ("  corrected" if result is not None else ""), (x0, y0 - 10 + 0), scale=0.5)
        gt = tracks.ground_truth_xy
        if gt is not None:
            _polyline(canvas, to_px(gt), GT, 5)
        _polyline(canvas, to_px(tracks.vo_xy), ODOMETRY, 1)
        _polyline(canvas, to_px(tracks.online_xy), ONLINE, 1)
        if corrected is not None:
            _polyline(canvas, to_px(corrected), CORRECTED, 2)
        segments = graph.segments()
        if len(segments):
            ends = to_px(segments.reshape(-1, 2)).reshape(-1, 2, 2)
            odometric = [s.astype(np.int32) for s in ends[~graph.is_loop]]
            cv2.polylines(canvas, odometric, False, LINK, 1, cv2.LINE_AA)
            loops = [s.astype(np.int32) for s in ends[graph.is_loop]]
            cv2.polylines(canvas, loops, False, LOOP, 2, cv2.LINE_AA)
        _squares(canvas, to_px(graph.vertices_xy), VERTEX, 2, (x0, y0, w, h))
        pose = np.asarray(record.online_pose, dtype=np.float64)
        if np.isfinite(pose).all():
            at = to_px(pose[:2])[0]
            tip = at + 14.0 * np.array([np.cos(pose[2]), -np.sin(pose[2])])
            cv2.circle(canvas, _pt(at), 5, BLACK, -1, cv2.LINE_AA)
            cv2.line(canvas, _pt(at), _pt(tip), BLACK, 2, cv2.LINE_AA)
        legend = [("odometry", ODOMETRY), ("online map track", ONLINE), ("links", LINK), ("loop links", LOOP),
                  ("vertices", VERTEX)]  # fmt: skip
        if gt is not None:
            legend.insert(0, ("ground truth", GT))
        if corrected is not None:
            legend.append(("corrected track", CORRECTED))
        for i, (label, colour) in enumerate(legend):
            y = y0 + h - 12 - 16 * (len(legend) - 1 - i)
            cv2.line(canvas, (x0 + 10, y - 4), (x0 + 34, y - 4), colour, 3)
            _text(canvas, label, (x0 + 40, y), scale=0.42)
        metres = _scale_bar_m(w * 0.25 / scale)
        bar = round(metres * scale)
        cv2.line(canvas, (x0 + w - 20 - bar, y0 + h - 16), (x0 + w - 20, y0 + h - 16), BLACK, 2)
        _text(canvas, f"{metres:g} m", (x0 + w - 20 - bar, y0 + h - 22), scale=0.42)


# ------------------------------------------------------------------------------------------------
# Drawing


def _text(canvas: np.ndarray, text: str, at: tuple[int, int], scale: float = 0.45, colour=TEXT) -> None:
    cv2.putText(canvas, text, (int(at[0]), int(at[1])), FONT, scale, colour, 1, cv2.LINE_AA)


def _pt(xy: np.ndarray) -> tuple[int, int]:
    return round(float(xy[0])), round(float(xy[1]))


def _polyline(canvas: np.ndarray, pixels: np.ndarray, colour: tuple, thickness: int) -> None:
    pixels = pixels[np.isfinite(pixels).all(axis=1)]
    if len(pixels) >= 2:
        cv2.polylines(canvas, [np.round(pixels).astype(np.int32)], False, colour, thickness, cv2.LINE_AA)


def _squares(canvas: np.ndarray, pixels: np.ndarray, colour: tuple, half: int, box: tuple) -> None:
    """A (2·half+1)-pixel square at every pixel position inside `box`, without a Python loop."""
    x0, y0, w, h = box
    pixels = np.round(pixels[np.isfinite(pixels).all(axis=1)]).astype(np.int64)
    for dx in range(-half, half + 1):
        for dy in range(-half, half + 1):
            u, v = pixels[:, 0] + dx, pixels[:, 1] + dy
            inside = (u >= x0) & (u < x0 + w) & (v >= y0) & (v < y0 + h)
            canvas[v[inside], u[inside]] = colour


def _scale_bar_m(metres: float) -> float:
    """A round length (1, 2 or 5 × 10^k m) not above `metres`."""
    if not metres > 0:
        return 1.0
    power = 10.0 ** np.floor(np.log10(metres))
    return float(max(m for m in (1.0, 2.0, 5.0) if m * power <= metres) * power)


def _draw_camera(canvas: np.ndarray, event: FrameEvent, box: tuple) -> None:
    x0, y0, w, h = box
    record = event.record
    left = np.asarray(event.frame.left)
    scale = min(w / left.shape[1], h / left.shape[0])
    size = (round(left.shape[1] * scale), round(left.shape[0] * scale))
    image = cv2.resize(left, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    canvas[y0 : y0 + size[1], x0 : x0 + size[0]] = image[..., None] if image.ndim == 2 else image
    pixels = event.features_px
    if pixels is not None:
        at = (pixels + 0.5) * scale - 0.5 + [x0, y0]
        _squares(canvas, at, FEATURE, 1, (x0, y0, size[0], size[1]))
    rows = event.view_rows
    label = view_cell_label(record)
    if rows is not None:
        top, bottom = (y0 + round(r * scale) for r in rows)
        colour = (0, 200, 255) if record.view_status == "familiar" else (255, 200, 0)
        cv2.rectangle(canvas, (x0, top), (x0 + size[0] - 1, bottom - 1), colour, 1)
    else:
        top, colour = y0, WHITE
    (text_w, text_h), _ = cv2.getTextSize(label, FONT, 0.45, 1)
    cv2.rectangle(canvas, (x0 + 1, top + 1), (x0 + 8 + text_w, top + 8 + text_h), BLACK, -1)
    _text(canvas, label, (x0 + 4, top + 4 + text_h), scale=0.45, colour=colour)


def _panel_image(panel: NeuralPanel, size: tuple[int, int]) -> np.ndarray:
    """The panel's image in BGR at `size` (w, h), nearest-neighbour (each unit stays a square)."""
    image = cv2.resize(panel.image, size, interpolation=cv2.INTER_NEAREST)
    return np.ascontiguousarray(image[..., ::-1])


def _draw_neural(canvas: np.ndarray, panels: list[NeuralPanel], box: tuple) -> int:
    """The HD ring across the width, then the tori side by side; returns the y below them."""
    x0, y0, w = box
    ring, tori = panels[0], panels[1:]
    _text(
        canvas,
        "HD-by-velocity ring: theta 0-360 deg (x), angular velocity (y); heading in red",
        (x0, y0 + 10),
    )
    ring_h = 56
    if ring.image is not None:
        canvas[y0 + 16 : y0 + 16 + ring_h, x0 : x0 + w] = _panel_image(ring, (w, ring_h))
        for bx, _by in ring.bumps_px:
            u = x0 + round(bx / ring.image.shape[1] * w)
            cv2.line(canvas, (u, y0 + 16), (u, y0 + 16 + ring_h - 1), BUMP, 2)
    y = y0 + 16 + ring_h + 26
    side = (w - 10 * (len(tori) - 1)) // max(len(tori), 1)
    side = min(side, 160)
    for j, panel in enumerate(tori):
        x = x0 + j * (side + 10)
        _text(canvas, panel.label, (x, y - 6), scale=0.42)
        if panel.image is None:
            cv2.rectangle(canvas, (x, y), (x + side, y + side), (200, 200, 200), 1)
            _text(canvas, "lesioned", (x + side // 2 - 32, y + side // 2), scale=0.5)
            continue
        canvas[y : y + side, x : x + side] = _panel_image(panel, (side, side))
        height, width = panel.image.shape[:2]
        for bx, by in panel.bumps_px:
            cv2.circle(
                canvas, (x + int(bx / width * side), y + int(by / height * side)), 3, BUMP, 1, cv2.LINE_AA
            )
    return y + side


def _draw_readout(canvas: np.ndarray, event: FrameEvent, at: tuple[int, int]) -> None:
    x, y = at
    record, readout = event.record, event.readout
    heading_deg = np.degrees(np.remainder(readout.heading_rad, 2 * np.pi))
    yaw_odometry, yaw_networks = np.degrees(record.yaw_rate_rad_s), np.degrees(readout.yaw_rate_rad_s)
    lines = [
        f"heading (HD ring) {heading_deg:6.1f} deg   yaw rate {yaw_odometry:6.1f} deg/s (odometry), "
        + f"{yaw_networks:6.1f} (HD ring)",
        f"speed {record.speed_m_s:5.2f} m/s (odometry)   view cells {event.view_cells}   vertex {record.vertex}"
        + (f"   closure: {record.closure_note}" if record.closure_note else ""),
    ]
    lines += bump_summary(readout)
    for i, line in enumerate(lines):
        _text(canvas, line, (x, y + 17 * i), scale=0.43)


def _check_codec() -> None:
    """Refuse before the run when this OpenCV cannot write MPEG-4 (rather than after the first frame)."""
    from hippo_nav._core import HippoNavError

    with tempfile.TemporaryDirectory(prefix="hippo_nav_video_") as folder:
        probe = Path(folder) / "probe.mp4"
        writer = cv2.VideoWriter(str(probe), cv2.VideoWriter.fourcc(*FOURCC), 10.0, (64, 64))
        ok = writer.isOpened()
        if ok:
            writer.write(np.zeros((64, 64, 3), np.uint8))
        writer.release()
        if not ok or not probe.exists() or probe.stat().st_size == 0:
            raise HippoNavError(
                f"this OpenCV ({cv2.__version__}) cannot write MPEG-4 video ('{FOURCC}'); --video needs an "
                "opencv-python build with FFmpeg (the PyPI wheels have it)"
            )
