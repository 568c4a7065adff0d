"""Live viewer: a pipeline observer that logs every frame of a run to Rerun (https://rerun.io).

`RerunObserver(target)` with `Pipeline(..., observers=[...])` or `hippo-nav run --rerun [FILE.rrd]`.
Without a target it spawns a Rerun Viewer (or connects to the one already listening on the default port);
with a path it saves a recording that `rerun FILE.rrd` opens later; a `rerun+http://…` URL connects there.
Needs the optional extra: `pip install 'hippo-nav[viewer]'` (rerun-sdk).

Everything is logged on the `frame` timeline (the sequence's frame number, as in frames.csv) and on `time`
(the frame's timestamp). Entities (docs/viewer.md):

- `camera/left` the left image at its own size; `camera/left/features` the stereo features the odometry
  tracks into the next frame; `camera/left/view_cell` the rows the view-cell template is cut from, labelled
  with the active view cell.
- `neural/hd_ring`, `neural/layer2_k{1,2,4}`, `neural/place`: the paper's neural-representation panel
  (`panels.neural_panels`), each with `…/bumps`, the decoded bump centres.
- `readout/heading_deg` (the HD ring's decoded heading), `readout/yaw_rate_deg_s` and `readout/speed_m_s`
  (two series each: the odometry's, which the networks integrate, and the networks' own — the HD ring's
  decoded yaw rate, the place code's displacement per second), `readout/bump_table` (the paper's table).
- `map/…`: the cognitive map growing — `map/vertices/<block>`, `map/links/<block>`, `map/loop_links`,
  `map/agent`, and the tracks `map/tracks/{odometry,online,ground_truth}/<block>` (`map/tracks/corrected`
  after the final correction). The map is drawn in the view's image coordinates, x forward and the map's
  y (left) upwards: a point (x, y) is logged at (x, −y).
- `timing/stage_ms`: per-stage wall time of the frame, one series per stage (`RunRecord.stage_s`); `record`
  includes the observers. `events`: loop closures and the end of the run.

Per-frame cost stays flat over a long run: growing point sets are logged in fixed-size blocks (one entity
each), and a frame re-logs only the blocks whose content changed — the last, growing one, or every block
whose vertices a loop closure's correction moved.
"""

from __future__ import annotations

import os
import socket
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hippo_nav._core import HippoNavError
from hippo_nav.engine import SpatialReadout
from hippo_nav.geometry import planar_xy
from hippo_nav.io.atomic import fresh_file_beside
from hippo_nav.pipeline.observers import FrameEvent
from hippo_nav.pipeline.records import RunResult
from hippo_nav.system.records import STAGES, FrameRecord
from hippo_nav.viewer.panels import (
    MapGraph,
    Tracks,
    bump_table,
    neural_panels,
    view_cell_label,
)

INSTALL_HINT = "pip install 'hippo-nav[viewer]'"
MIN_RERUN = (0, 23)  # `RecordingStream.set_time(..., sequence=)` and `rr.Scalars`
BLOCK = 64  # points (vertices, links, track samples) per logged block
FLUSH_TIMEOUT_S = 10.0  # at the end of a run, for a viewer that is not taking data
VIEWER_PORT = 9876  # where `spawn` starts the viewer, or finds one already running
JPEG_ABOVE_PX = 200_000  # camera images with more pixels are logged as JPEG (a KITTI frame: 466 000)

# Colours (RGB) as in cognitive_map.png; sizes in UI points (rerun reads negative radii as screen sizes), so a
# kilometre-wide map and a 96-pixel image are drawn alike at any zoom.
GREEN, GREY, RED, BLACK = (44, 160, 44), (128, 128, 128), (220, 0, 0), (0, 0, 0)
ORANGE, BLUE = (255, 127, 14), (31, 119, 180)
UI_VERTEX, UI_LINK, UI_LOOP, UI_TRACK, UI_FEATURE, UI_BUMP = -2.5, -0.75, -1.5, -1.0, -2.0, -3.0
TRACK_STYLE = {
    "odometry": ORANGE,
    "online": BLUE,
    "ground_truth": (110, 110, 110),
    "corrected": (148, 103, 189),
}


def import_rerun() -> Any:
    """The `rerun` module, or a `HippoNavError` saying how to install it (the CLI prints it and exits 2)."""
    from hippo_nav._core import HippoNavError

    try:
        import rerun
    except ImportError:
        raise HippoNavError(f"the Rerun viewer is an optional extra: {INSTALL_HINT}") from None
    version = getattr(rerun, "__version__", "0")
    try:
        numbers = tuple(int(part) for part in version.split(".")[:2])
    except ValueError:
        numbers = MIN_RERUN  # a development build: trust it
    if numbers < MIN_RERUN:
        raise HippoNavError(
            f"rerun-sdk {version} is too old (need ≥ {'.'.join(map(str, MIN_RERUN))}): pip install -U 'hippo-nav[viewer]'"
        )
    return rerun


class _Blocks:
    """A growing (n, …) array logged in blocks of `BLOCK` rows, one entity per block (`entity/<b>`). `update`
    re-logs only the blocks whose rows changed; `overlap` repeats the next block's first row at the end of
    each block, so that polylines drawn block by block stay joined. `style` (archetype name, fields): logged
    once per block entity, static (see `_Style`)."""

    def __init__(
        self,
        rr: Any,
        entity: str,
        make: Callable[[np.ndarray], Any],
        style: tuple[str, dict[str, Any]],
        overlap: int = 0,
    ) -> None:
        self.rr, self.entity, self.make, self.style, self.overlap = rr, entity, make, style, overlap
        self._logged: list[np.ndarray] = []

    def update(self, rec: Any, rows: np.ndarray, first_block: int = 0) -> int:
        """Log what changed from block `first_block` on (later blocks are always compared); returns the
        number of blocks logged."""
        n_blocks = -(-len(rows) // BLOCK)
        logged = 0
        for b in range(min(first_block, len(self._logged)), n_blocks):
            block = rows[b * BLOCK : (b + 1) * BLOCK + self.overlap]
            if b < len(self._logged) and np.array_equal(self._logged[b], block):
                continue
            if b < len(self._logged):
                self._logged[b] = block.copy()
            else:
                _log_style(self.rr, rec, f"{self.entity}/{b}", *self.style)
                self._logged.append(block.copy())
            rec.log(f"{self.entity}/{b}", self.make(block))
            logged += 1
        for b in range(n_blocks, len(self._logged)):  # the array shrank (a map reloaded): clear the rest
            rec.log(f"{self.entity}/{b}", self.rr.Clear(recursive=False))
        del self._logged[n_blocks:]
        return logged

    @property
    def last_block(self) -> int:
        return max(len(self._logged) - 1, 0)


def _log_style(rr: Any, rec: Any, entity: str, kind: str, fields: dict[str, Any]) -> None:
    """Colours and sizes of an entity, logged once and static: the frames then log only positions (an
    archetype's fields left out are kept), which halves the cost of a log call."""
    rec.log(entity, getattr(rr, kind).from_fields(**fields), static=True)


def _writable_file(path: Path) -> Path:
    """`path`, once it is clear that a file can be written there (its folder need not exist yet)."""
    from hippo_nav._core import HippoNavError

    if path.is_dir():
        raise HippoNavError(f"rerun recording {path} is a folder; give a file path ending in .rrd")
    folder = next((p for p in (path.parent, *path.parent.parents) if p.exists()), Path("."))
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        raise HippoNavError(f"rerun recording {path} cannot be written ({folder} is not a writable folder)")
    return path


def _check_viewer_can_start() -> None:
    """`spawn` starts the Rerun Viewer (a window) unless one already listens on its port. Without a
    display the viewer exits at once and every later flush waits for it forever: refuse before the run."""
    from hippo_nav._core import HippoNavError

    if not sys.platform.startswith("linux") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.5)
        if probe.connect_ex(("127.0.0.1", VIEWER_PORT)) == 0:
            return  # a viewer is already running (e.g. `rerun --serve-web`): spawn connects to it
    raise HippoNavError(
        "--rerun without a file shows the Rerun Viewer, and this machine has no display (DISPLAY and "
        f"WAYLAND_DISPLAY are unset, and no viewer listens on port {VIEWER_PORT}); save a recording with "
        "--rerun FILE.rrd and open it with `rerun FILE.rrd` where there is a display"
    )


def _screen(xy: np.ndarray) -> np.ndarray:
    """Map-frame (x forward, y left) → the 2-D view's coordinates (y down): (x, −y)."""
    out = np.array(xy, dtype=np.float32).reshape(-1, 2)
    out[:, 1] *= -1.0
    return out


class RerunObserver:
    """Logs a run to Rerun, frame by frame (module doc). `target`: None (spawn or connect to a viewer), a
    `.rrd` path (save a recording) or a `rerun+http://…` URL; `recording`: an existing `RecordingStream`
    instead (then `target` is ignored). `rr` replaces the rerun module (tests)."""

    def __init__(
        self,
        target: str | Path | None = None,
        *,
        recording: Any = None,
        application_id: str = "hippo_nav",
        rr: Any = None,
    ) -> None:
        self.rr = rr if rr is not None else import_rerun()
        self.target = target
        self._save_to: Path | None = None
        self._partial: Path | None = None
        self._closed = False
        if recording is None:
            recording = self.rr.RecordingStream(application_id)
            if target is None:
                _check_viewer_can_start()
                recording.spawn()
            elif str(target).startswith(("rerun://", "rerun+http://", "rerun+https://")):
                recording.connect_grpc(str(target))
            else:
                # Saved from the first frame on: the file may live in the results folder, which the
                # pipeline checks (it must be empty) and creates before the first frame.
                self._save_to = _writable_file(Path(target))
        self.rec = recording
        self.frames_logged = 0
        self._tracks = Tracks()
        self._graph: MapGraph | None = None
        self._map_size = -1
        self._vertex = -2
        rr_ = self.rr
        self._vertices = _Blocks(
            rr_,
            "map/vertices",
            lambda xy: rr_.Points2D(_screen(xy)),
            ("Points2D", {"radii": UI_VERTEX, "colors": GREEN}),
        )
        self._links = _Blocks(
            rr_,
            "map/links",
            lambda seg: rr_.LineStrips2D([_screen(s) for s in seg]),
            ("LineStrips2D", {"radii": UI_LINK, "colors": GREY}),
        )
        self._track_blocks = {
            name: _Blocks(
                rr_,
                f"map/tracks/{name}",
                lambda xy: rr_.LineStrips2D([_screen(xy)]),
                ("LineStrips2D", {"radii": UI_TRACK, "colors": colour}),
                overlap=1,
            )
            for name, colour in TRACK_STYLE.items()
            if name != "corrected"
        }
        self._loops_logged = np.zeros((0, 2, 2))
        self._last_place: tuple[np.ndarray, float] | None = None  # place code (m) and time of the last frame
        self._previous: FrameRecord | None = None  # the record of the frame logged before

    # ----------------------------------------------------------------------------------------------
    def on_frame(self, event: FrameEvent) -> None:
        rec, rr = self.rec, self.rr
        record = event.record
        if self.frames_logged == 0:
            self._start(event)
        self._at(record)
        self._log_camera(event)
        for panel in neural_panels(event.network, event.readout):
            if panel.image is None:
                continue
            rec.log(f"neural/{panel.name}", rr.Image(panel.image))
            rec.log(f"neural/{panel.name}/bumps", rr.Points2D(panel.bumps_px))
        self._log_readout(record, event.readout)
        self._log_map(event)
        if record.loop_closure is not None:
            rec.log("events", rr.TextLog(f"loop closure {record.loop_closure[0]} → {record.loop_closure[1]}"))
        if self._previous is not None and event.previous_stage_s is not None:
            self._log_timing(self._previous, event.previous_stage_s)  # last: it moves the time cursor back
        self._previous = record
        self.frames_logged += 1

    def on_finish(self, result: RunResult) -> None:
        """The corrected map and track after the final correction, at the last frame; then flush."""
        rec, rr = self.rec, self.rr
        if self.frames_logged == 0:
            return
        last = result.record.frames[-1]
        self._at(last)
        graph = MapGraph.from_export(result.map_export)
        self._vertices.update(rec, graph.vertices_xy)
        self._links.update(rec, graph.segments()[~graph.is_loop])
        self._log_loops(graph)
        corrected = result.corrected_world_from_camera
        rec.log(
            "map/tracks/corrected",
            rr.LineStrips2D([_screen(planar_xy(corrected))]),
        )
        ate = (result.metrics.get("errors") or {}).get("corrected", {}).get("ate_2d_m")
        note = f", corrected ATE {ate:.2f} m" if isinstance(ate, float) else ""
        state = "interrupted" if result.interrupted else "finished"
        rec.log("events", rr.TextLog(f"run {state} after {len(result.record)} frames{note}"))
        stage_s = result.record.stage_s
        if all(len(stage_s.get(stage, [])) == len(result.record) for stage in STAGES):
            self._log_timing(last, {stage: stage_s[stage][-1] for stage in STAGES})
        self._flush()

    def _at(self, record: FrameRecord) -> None:
        """Log what follows at this frame, on both timelines."""
        self.rec.set_time("frame", sequence=int(record.frame_index))
        self.rec.set_time("time", duration=float(record.timestamp_s))

    def close(self) -> None:
        """Flush and close the recording (the .rrd file is complete after this), waiting at most
        `FLUSH_TIMEOUT_S` for each: a program on the viewer's port that takes the connection but is not a
        viewer (or a viewer that hangs) would otherwise hold the finished run for ever, in the close and
        again in Rerun's own shutdown when the process exits."""
        if self._closed:
            return
        self._closed = True
        unflushed = self._flush()
        closing = threading.Thread(target=self.rec.disconnect, name="rerun-disconnect", daemon=True)
        closing.start()
        closing.join(FLUSH_TIMEOUT_S)
        if closing.is_alive():
            import logging

            logging.getLogger("hippo_nav.viewer").warning(
                "the Rerun viewer did not close the connection within %.0f s (is another program listening "
                "on port %d?); not waiting for it: the run's results are written",
                FLUSH_TIMEOUT_S, VIEWER_PORT,
            )  # fmt: skip
            # Rerun's exit handler would wait for that connection too, and the process would never end.
            unregister = getattr(self.rr, "unregister_shutdown", None)
            if unregister is not None:
                unregister()
            return
        if self._partial is not None and self._save_to is not None:
            partial, self._partial = self._partial, None
            if unflushed is not None:
                # Rerun could not write the rest (a full disk): the file is cut short, and a file at the
                # target's name is a whole recording.
                partial.unlink(missing_ok=True)
                raise HippoNavError(
                    f"the Rerun recording {self._save_to} could not be finished ({unflushed}); nothing was "
                    "put at that name (is the disk full?)"
                )
            os.replace(partial, self._save_to)

    def _flush(self) -> Exception | None:
        """Flush, waiting at most `FLUSH_TIMEOUT_S`: a viewer that went away (or never came up) must not
        hold a finished run forever; its results are written before this. The error, or None."""
        try:
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except Exception as err:  # noqa: BLE001 - rerun raises its own error types; the run is done anyway
            if self._save_to is not None:
                return err  # a recording to a file: `close` says it could not be finished
            import logging

            logging.getLogger("hippo_nav.viewer").warning(
                "the Rerun viewer did not take the last data within %.0f s (%s); the run's results are "
                "written, the viewer may miss its last frames",
                FLUSH_TIMEOUT_S, err,
            )  # fmt: skip
        return None

    # ----------------------------------------------------------------------------------------------
    def _start(self, event: FrameEvent) -> None:
        """Static things and the layout, once the networks' shapes are known."""
        rr = self.rr
        if self._save_to is not None:
            # Recorded under a fresh name created exclusively beside the target (no link followed), which
            # `close` renames to the target: a file at the target's name is always a whole recording.
            self._save_to.parent.mkdir(parents=True, exist_ok=True)
            self._partial = fresh_file_beside(self._save_to, ".rrd")
            self.rec.save(self._partial)
        names = [p.name for p in neural_panels(event.network, event.readout)]
        series = {
            "readout/yaw_rate_deg_s": ["odometry", "HD ring"],
            "readout/speed_m_s": ["odometry", "networks (place code)"],
            "timing/stage_ms": list(STAGES),
        }
        for entity, names in series.items():
            self.rec.log(entity, rr.SeriesLines(names=names), static=True)
        styles = {
            "camera/left/features": ("Points2D", {"radii": UI_FEATURE, "colors": (0, 255, 0)}),
            "map/agent": ("Arrows2D", {"radii": UI_LOOP, "colors": BLACK}),
            "map/loop_links": ("LineStrips2D", {"radii": UI_LOOP, "colors": RED}),
            "map/tracks/corrected": ("LineStrips2D", {"radii": UI_TRACK, "colors": TRACK_STYLE["corrected"]}),
            **{
                f"neural/{name}/bumps": ("Points2D", {"radii": UI_BUMP, "colors": (255, 60, 60)})
                for name in names
            },
        }
        for entity, (kind, fields) in styles.items():
            _log_style(rr, self.rec, entity, kind, fields)
        try:
            self.rec.send_blueprint(_blueprint(rr, names))
        except Exception as err:  # noqa: BLE001 - the layout is a convenience (and rerun's API moves): never stop a run
            import logging

            logging.getLogger("hippo_nav.viewer").warning(
                "rerun layout not sent (%s); using rerun's default", err
            )

    def _log_camera(self, event: FrameEvent) -> None:
        rec, rr = self.rec, self.rr
        record = event.record
        left = np.asarray(event.frame.left)
        if left.size > JPEG_ABOVE_PX:
            ok, jpeg = cv2.imencode(".jpg", left, [cv2.IMWRITE_JPEG_QUALITY, 85])
            image = (
                rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg") if ok else rr.Image(left)
            )
        else:
            image = rr.Image(left)
        rec.log("camera/left", image)
        pixels = event.features_px
        if pixels is not None:
            rec.log("camera/left/features", rr.Points2D(pixels + 0.5))
        # The rows the descriptor looks at (the template's crop), or the whole image (features from all of it).
        top, bottom = event.view_rows if event.view_rows is not None else (0, left.shape[0])
        colour = (255, 200, 0) if record.view_status == "familiar" else (0, 200, 255)
        rec.log(
            "camera/left/view_cell",
            rr.Boxes2D(
                mins=[[0.0, float(top)]], sizes=[[float(left.shape[1]), float(bottom - top)]],
                labels=[view_cell_label(record)], colors=[colour],
            ),
        )  # fmt: skip

    def _log_readout(self, record: FrameRecord, readout: SpatialReadout) -> None:
        """Heading; yaw rate and speed as two series each (the odometry's, which the networks integrate, and
        the networks' own: the HD ring's decoded yaw rate, the place code's displacement per second)."""
        rec, rr = self.rec, self.rr
        rec.log("readout/heading_deg", rr.Scalars(np.degrees(np.remainder(readout.heading_rad, 2 * np.pi))))
        rec.log(
            "readout/yaw_rate_deg_s",
            rr.Scalars(np.degrees([record.yaw_rate_rad_s, readout.yaw_rate_rad_s])),
        )
        place, time_s = np.asarray(readout.place_position_m, dtype=np.float64), float(record.timestamp_s)
        speed = np.nan  # no networks' speed on the first frame
        if self._last_place is not None and time_s > self._last_place[1]:
            speed = float(np.linalg.norm(place - self._last_place[0])) / (time_s - self._last_place[1])
        self._last_place = (place, time_s)
        rec.log("readout/speed_m_s", rr.Scalars([record.speed_m_s, speed]))
        table = bump_table(readout, record.frame_index)
        rec.log("readout/bump_table", rr.TextDocument(f"```\n{table}\n```", media_type="text/markdown"))

    def _log_map(self, event: FrameEvent) -> None:
        rec, rr = self.rec, self.rr
        record = event.record
        self._tracks.update(event)
        # The graph's links change only when the agent moves to another vertex or closes a loop.
        size = event.vertices
        if size != self._map_size or record.vertex != self._vertex or record.loop_closure is not None:
            self._graph = MapGraph.from_export(event.map_export)
            self._map_size, self._vertex = size, record.vertex
        graph = self._graph
        if graph is not None and len(graph.vertices_xy):
            # Vertex positions move only when a correction ran; reading them is cheap, logging is not.
            xy = event.vertex_poses[:, :2]
            self._vertices.update(rec, xy)
            segments = graph.segments(xy)
            self._links.update(rec, segments[~graph.is_loop])
            self._log_loops(MapGraph(xy, graph.links, graph.is_loop))
        tracks = {"odometry": self._tracks.vo_xy, "online": self._tracks.online_xy}
        if self._tracks.ground_truth_xy is not None:
            tracks["ground_truth"] = self._tracks.ground_truth_xy
        for name, xy in tracks.items():
            blocks = self._track_blocks[name]
            blocks.update(rec, xy, first_block=blocks.last_block)  # tracks only grow: skip settled blocks
        pose = np.asarray(record.online_pose, dtype=np.float64)
        heading = np.array([np.cos(pose[2]), np.sin(pose[2])]) * 3.0
        rec.log(
            "map/agent",
            rr.Arrows2D(origins=_screen(pose[:2]), vectors=_screen(heading)),
        )

    def _log_loops(self, graph: MapGraph) -> None:
        loops = graph.segments()[graph.is_loop]
        if loops.shape == self._loops_logged.shape and np.array_equal(loops, self._loops_logged):
            return
        self.rec.log("map/loop_links", self.rr.LineStrips2D([_screen(s) for s in loops]))
        self._loops_logged = loops

    def _log_timing(self, record: FrameRecord, stage_s: Mapping[str, float]) -> None:
        """Every stage's wall time (ms) of the frame of `record`, as one multi-series entity. The `record`
        stage (which includes the observers) ends after `on_frame`, so a frame's timings are logged by the
        next frame (the last one's by `on_finish`), at the frame they belong to."""
        self._at(record)
        self.rec.log("timing/stage_ms", self.rr.Scalars([1e3 * stage_s[stage] for stage in STAGES]))


def _blueprint(rr: Any, panels: Sequence[str]) -> Any:
    """The default layout: camera and neural panels on the left, the map on the right, plots below."""
    rrb = rr.blueprint
    neural = [rrb.Spatial2DView(origin=f"/neural/{name}", name=name) for name in panels]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(origin="/camera/left", name="left camera"),
                rrb.Grid(*neural, name="neural representation"),
                rrb.Horizontal(
                    rrb.Vertical(
                        rrb.TimeSeriesView(origin="/readout/heading_deg", name="heading (deg)"),
                        rrb.TimeSeriesView(origin="/readout/yaw_rate_deg_s", name="yaw rate (deg/s)"),
                        rrb.TimeSeriesView(origin="/readout/speed_m_s", name="speed (m/s)"),
                    ),
                    rrb.TextDocumentView(origin="/readout/bump_table", name="bump table"),
                ),
                row_shares=[1, 2, 1.3],
            ),
            rrb.Vertical(
                rrb.Spatial2DView(origin="/map", name="cognitive map"),
                rrb.Horizontal(
                    rrb.TimeSeriesView(origin="/timing", name="stage time (ms)"),
                    rrb.TextLogView(origin="/events", name="events"),
                ),
                row_shares=[3, 1],
            ),
            column_shares=[1, 1],
        ),
        collapse_panels=True,
    )
